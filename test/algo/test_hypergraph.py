"""HGCN against a dense hand computation; Binary Concrete statistics; gradient paths."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sdhn_train.algorithms.sdhn.critic import SDHNCritic
from sdhn_train.algorithms.sdhn.hypergraph import HGCNLayer, binary_concrete, hgcn_propagate
from sdhn_train.algorithms.sdhn.skewness import (
    hyperedge_degrees,
    sample_skewness,
    skewness_loss,
    squashed_skewness,
)


def dense_hgcn(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """D^-1/2 H B^-1 H^T D^-1/2 X with explicit diagonal matrices and pseudo-inverses."""
    d = h.sum(1)
    b = h.sum(0)
    d_is = np.diag([v**-0.5 if v > 0 else 0.0 for v in d])
    b_i = np.diag([1.0 / v if v > 0 else 0.0 for v in b])
    return d_is @ h @ b_i @ h.T @ d_is @ x


def test_hgcn_matches_hand_computed_example_with_empty_edge_and_isolated_vertex() -> None:
    # 4 vertices, 3 hyperedges: e0={0,1,2}, e1={2}, e2={} (empty); vertex 3 isolated.
    h = np.array([[1, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0]], dtype=np.float64)
    x = np.array([[1.0, 2.0], [3.0, -1.0], [0.5, 4.0], [7.0, 7.0]])
    # by hand: d = (1, 1, 2, 0), b = (3, 1, 0)
    s2 = 2**-0.5
    xs = x * np.array([1, 1, s2, 0])[:, None]  # D^-1/2 X
    e0 = (xs[0] + xs[1] + xs[2]) / 3
    e1 = xs[2] / 1
    by_hand = np.stack([e0, e0, s2 * (e0 + e1), np.zeros(2)])
    np.testing.assert_allclose(dense_hgcn(x, h), by_hand, atol=1e-12)
    got = hgcn_propagate(torch.tensor(x)[None], torch.tensor(h)[None])[0].numpy()
    np.testing.assert_allclose(got, by_hand, atol=1e-12)
    assert np.all(got[3] == 0), "an isolated vertex must receive exactly 0"


def test_hgcn_layer_is_relu_of_propagation_times_theta_on_random_graphs() -> None:
    rng = np.random.default_rng(1)
    layer = HGCNLayer(5, 3).double()
    for _ in range(5):
        h = (rng.random((6, 4)) < 0.4).astype(np.float64)
        x = rng.normal(size=(6, 5))
        theta = layer.theta.weight.detach().numpy().T
        want = np.maximum(dense_hgcn(x, h) @ theta, 0.0)
        got = layer(torch.tensor(x)[None], torch.tensor(h)[None])[0].detach().numpy()
        np.testing.assert_allclose(got, want, atol=1e-10)


def test_binary_concrete_logistic_mean_matches_p() -> None:
    p = torch.tensor([0.05, 0.2, 0.5, 0.8, 0.97])
    logits = torch.log(p) - torch.log1p(-p)
    h, _ = binary_concrete(logits.expand(200_000, 5), tau=1.0, noise="logistic")
    mean = h.mean(0)
    assert torch.all((mean - p).abs() < 0.01), f"empirical P(H=1) {mean.tolist()} vs p {p.tolist()}"
    assert set(h.unique().tolist()) <= {0.0, 1.0}


def test_binary_concrete_paper_noise_and_deterministic_switch() -> None:
    logits = torch.tensor([-2.0, 0.3, 2.0])
    h, _ = binary_concrete(logits.expand(50_000, 3), tau=0.5, noise="gumbel_paper")
    assert set(h.unique().tolist()) <= {0.0, 1.0}
    h_det, _ = binary_concrete(logits, tau=1.0, stochastic=False)
    assert h_det.tolist() == [0.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="noise"):
        binary_concrete(logits, tau=1.0, noise="bad")  # type: ignore[arg-type]


def test_straight_through_gradient_equals_gradient_of_y() -> None:
    logits = torch.tensor([0.3, -1.2], requires_grad=True)
    torch.manual_seed(3)
    h, _ = binary_concrete(logits, tau=0.7)
    (h * torch.tensor([2.0, 5.0])).sum().backward()
    g_h = logits.grad.clone()
    logits.grad = None
    torch.manual_seed(3)
    _, y2 = binary_concrete(logits, tau=0.7)
    (y2 * torch.tensor([2.0, 5.0])).sum().backward()
    torch.testing.assert_close(g_h, logits.grad)
    assert torch.all(g_h != 0)


def _critic(**kw: object) -> SDHNCritic:
    return SDHNCritic(obs_size=6, state_size=24, num_robots=4, num_hyperedges=5,
                      generator_hidden=16, hgcn_hidden=8, state_hidden=8, **kw)  # type: ignore[arg-type]


def _sequence(t: int = 3, b: int = 2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    obs = torch.randn(t, b, 4, 6)
    return obs, obs.reshape(t, b, -1), torch.zeros(t, b, dtype=torch.bool)


def test_td_loss_gradient_reaches_generator_through_h() -> None:
    critic = _critic(skew_loss=False)
    obs, state, resets = _sequence()
    out = critic.forward_sequence(obs, state, critic.initial_state(2), resets)
    (out.values**2).mean().backward()
    g = critic.generator.to_logits.weight.grad
    assert g is not None and g.abs().sum() > 0, "TD loss must reach f_g through straight-through H"


def test_skew_loss_gradient_reaches_generator() -> None:
    critic = _critic(skew_loss=True)
    obs, state, resets = _sequence(t=4, b=8)
    out = critic.forward_sequence(obs, state, critic.initial_state(8), resets)
    out.aux_loss.backward()
    grads = [p.grad for p in critic.generator.parameters()]
    assert all(g is not None for g in grads)
    assert sum(float(g.abs().sum()) for g in grads if g is not None) > 0
    for name, p in critic.named_parameters():  # L_Sk depends on theta_hg only (eq. total_loss)
        if not name.startswith("generator."):
            assert p.grad is None or p.grad.abs().sum() == 0, name


def test_skewness_equals_scipy_biased() -> None:
    stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(0)
    b = rng.integers(0, 11, size=(200, 10)).astype(np.float64)
    b = b[b.std(1) > 0]
    got = sample_skewness(torch.tensor(b)).numpy()
    np.testing.assert_allclose(got, stats.skew(b, axis=1, bias=True), rtol=1e-10, atol=1e-12)


def test_equal_degrees_give_finite_loss_and_gradient() -> None:
    logits = torch.full((2, 4, 5), 3.0, requires_grad=True)  # every robot in every hyperedge
    h, _ = binary_concrete(logits, tau=1.0, stochastic=False)
    b = hyperedge_degrees(h)
    assert torch.all(b == 4)
    gamma = sample_skewness(b)
    loss = skewness_loss(squashed_skewness(gamma), -0.6)
    loss.backward()
    assert torch.isfinite(loss) and torch.all(gamma == 0)
    assert logits.grad is not None and torch.all(torch.isfinite(logits.grad))


def test_squashed_skewness_range_and_loss_value() -> None:
    sk = squashed_skewness(torch.tensor([-50.0, 0.0, 50.0]))
    torch.testing.assert_close(sk, torch.tensor([-1.0, 0.0, 1.0]))
    torch.testing.assert_close(skewness_loss(torch.tensor([0.0]), -0.6), torch.tensor(0.36))


def test_split_value_head_equals_head_of_concatenation() -> None:
    """The critic's first value-head layer runs split (state part once per team); values and
    every gradient equal value_head(cat([s expanded over robots, m])) to 1e-5."""
    critic = _critic(skew_loss=False)
    s = torch.randn(5, 3, 8, requires_grad=True)  # state_hidden 8
    m = torch.randn(5, 3, 4, 8, requires_grad=True)  # 4 robots, hgcn_hidden 8
    got = critic._head(s, m)
    grads = torch.autograd.grad(got.square().sum(), [s, m, *critic.value_head.parameters()])
    want = critic.value_head(torch.cat([s.unsqueeze(-2).expand(5, 3, 4, 8), m], -1)).squeeze(-1)
    want_grads = torch.autograd.grad(want.square().sum(),
                                     [s, m, *critic.value_head.parameters()])
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    for g, w in zip(grads, want_grads, strict=True):
        torch.testing.assert_close(g, w, atol=1e-5, rtol=1e-5)
