"""The fused GRU (sdhn_train.fused_gru) gives nn.GRU's numbers: outputs, hidden states and
every gradient to 1e-5 (a whole PPO update with it: test_speed_options)."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from sdhn_policy.actor_torch import gru_sequence
from sdhn_train.fused_gru import fused_gru_sequence, use_fused_gru


def _run(fn, gru: nn.GRU, inputs: tuple[torch.Tensor, ...], weight: torch.Tensor):  # type: ignore[no-untyped-def]
    gru.zero_grad(set_to_none=True)
    x, h0, resets = inputs
    x, h0 = x.detach().requires_grad_(True), h0.detach().requires_grad_(True)
    out, hiddens = fn(gru, x, h0, resets)
    (out * weight).sum().backward()
    grads = {name: p.grad.clone() for name, p in gru.named_parameters()}
    assert x.grad is not None and h0.grad is not None
    return out.detach(), hiddens, x.grad, h0.grad, grads


@pytest.mark.parametrize("layers", [1, 3])
@pytest.mark.parametrize("reset_rate", [0.0, 0.1])
def test_fused_gru_equals_nn_gru_outputs_and_gradients(layers: int, reset_rate: float) -> None:
    t_len, b, d, h = 40, 6, 9, 16
    gru = nn.GRU(d, h, num_layers=layers)
    x = torch.randn(t_len, b, d) * 2
    h0 = torch.randn(layers, b, h)
    resets = torch.rand(t_len, b) < reset_rate
    if reset_rate:
        resets[0, 0] = True  # a reset at step 0 zeroes h0 of that env
    weight = torch.randn(t_len, b, h)
    want = _run(gru_sequence, gru, (x, h0, resets), weight)
    got = _run(fused_gru_sequence, gru, (x, h0, resets), weight)
    torch.testing.assert_close(got[0], want[0], atol=1e-5, rtol=0)
    ends = [t_len - 1, *resets[1:].any(1).nonzero().flatten().tolist()]
    torch.testing.assert_close(got[1][ends], want[1][ends], atol=1e-5, rtol=0)  # segment ends
    torch.testing.assert_close(got[1][:, -1], got[0])  # fused: every step's hidden state
    torch.testing.assert_close(got[2], want[2], atol=1e-5, rtol=0)  # d x
    torch.testing.assert_close(got[3], want[3], atol=1e-5, rtol=0)  # d h0
    for name, g in want[4].items():
        torch.testing.assert_close(got[4][name], g, atol=1e-5, rtol=1e-5, msg=name)


def test_fused_gru_gradients_pass_gradcheck_in_double() -> None:
    from sdhn_train.fused_gru import gru_layer

    t_len, b, d, h = 7, 3, 4, 5
    args = [torch.randn(t_len, b, d), torch.randn(b, h), torch.randn(3 * h, d),
            torch.randn(3 * h, h), torch.randn(3 * h), torch.randn(3 * h)]
    args = [a.double().requires_grad_(True) for a in args]
    resets = torch.zeros(t_len, b, dtype=torch.bool)
    resets[3, 1] = True
    assert torch.autograd.gradcheck(
        lambda x, h0, *w: gru_layer(x, h0, tuple(w), resets), args)  # type: ignore[arg-type]


def test_without_gradients_fused_is_the_nn_gru_path() -> None:
    gru = nn.GRU(5, 8, num_layers=2)
    x, h0 = torch.randn(10, 3, 5), torch.zeros(2, 3, 8)
    resets = torch.zeros(10, 3, dtype=torch.bool)
    resets[4, 2] = True
    with torch.no_grad():
        want, want_h = gru_sequence(gru, x, h0, resets)
        got, got_h = fused_gru_sequence(gru, x, h0, resets)
    assert torch.equal(got, want) and torch.equal(got_h, want_h)


def test_use_fused_gru_switches_every_sequence_module() -> None:
    from sdhn_train.algorithms.sdhn.critic import SDHNCritic

    critic = SDHNCritic(6, 10, 3)
    use_fused_gru(critic)
    assert critic.generator.gru_sequence is fused_gru_sequence
    use_fused_gru(critic, fused=False)
    assert critic.generator.gru_sequence is gru_sequence
