"""GAE vs a naive double loop, PPO clipping at the ratio bounds, soft-update arithmetic."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from sdhn_train.learners.ppo import clipped_policy_loss, soft_update
from sdhn_train.returns import gae_advantages, td_errors, value_targets


def naive_gae(r, v, v_next, term, done, gamma, lam):  # type: ignore[no-untyped-def]  # noqa: PLR0917
    t_len, b = r.shape
    adv = np.zeros_like(v)
    for t in range(t_len):
        for j in range(b):
            total, discount = 0.0, 1.0
            for k in range(t, t_len):
                delta = r[k, j] + gamma * (1 - term[k, j]) * v_next[k, j] - v[k, j]
                total += discount * delta
                if done[k, j]:
                    break
                discount *= gamma * lam
            adv[t, j] = total
    return adv


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gae_matches_naive_double_loop(seed: int) -> None:
    rng = np.random.default_rng(seed)
    t_len, b = 17, 5
    r, v, v_next = (rng.normal(size=(t_len, b)) for _ in range(3))
    term = rng.random((t_len, b)) < 0.1
    trunc = (rng.random((t_len, b)) < 0.1) & ~term
    done = term | trunc
    want = naive_gae(r, v, v_next, term, done, 0.97, 0.9)
    deltas = td_errors(torch.tensor(r), torch.tensor(v), torch.tensor(v_next),
                       torch.tensor(term), 0.97)
    got = gae_advantages(deltas, torch.tensor(done), 0.97, 0.9)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-10)
    np.testing.assert_allclose(value_targets(got, torch.tensor(v)).numpy(), want + v, atol=1e-10)


def test_gae_broadcasts_team_reward_over_robots() -> None:
    r = torch.tensor([[1.0], [2.0]])
    v = torch.zeros(2, 1, 3)
    deltas = td_errors(r, v, v, torch.zeros(2, 1, dtype=torch.bool), 0.5)
    adv = gae_advantages(deltas, torch.zeros(2, 1, dtype=torch.bool), 0.5, 1.0)
    torch.testing.assert_close(adv[0, 0], torch.full((3,), 2.0))


def test_ppo_clip_stops_gradient_beyond_ratio_bounds() -> None:
    eps = 0.2
    old = torch.zeros(4)
    # ratios 1.5 and 0.5 (outside), 1.1 and 0.9 (inside); advantages +,-,+,-
    new = torch.log(torch.tensor([1.5, 0.5, 1.1, 0.9])).requires_grad_(True)
    adv = torch.tensor([1.0, -1.0, 1.0, -1.0])
    loss, _, clipfrac = clipped_policy_loss(new, old, adv, eps)
    loss.backward()
    # positive A with ratio > 1+eps and negative A with ratio < 1-eps are clipped: zero gradient
    assert new.grad is not None
    assert new.grad[0] == 0 and new.grad[1] == 0
    assert new.grad[2] != 0 and new.grad[3] != 0
    assert clipfrac == pytest.approx(0.5)
    want = -np.mean([1.2 * 1, -0.8, 1.1, -0.9])
    assert float(loss.detach()) == pytest.approx(want)


def test_ppo_clip_keeps_gradient_on_the_pessimistic_side() -> None:
    new = torch.log(torch.tensor([1.5, 0.5])).requires_grad_(True)
    adv = torch.tensor([-1.0, 1.0])  # ratio high with negative A, low with positive A: unclipped
    loss, _, _ = clipped_policy_loss(new, torch.zeros(2), adv, 0.2)
    loss.backward()
    assert new.grad is not None and torch.all(new.grad != 0)
    assert float(loss.detach()) == pytest.approx(-np.mean([-1.5, 0.5]))


def test_soft_update_arithmetic() -> None:
    src, tgt = nn.Linear(3, 2), nn.Linear(3, 2)
    before = [p.detach().clone() for p in tgt.parameters()]
    soft_update(tgt, src, 0.01)
    for b, s, t in zip(before, src.parameters(), tgt.parameters(), strict=True):
        torch.testing.assert_close(t, 0.99 * b + 0.01 * s.detach())
    soft_update(tgt, src, 1.0)
    for s, t in zip(src.parameters(), tgt.parameters(), strict=True):
        torch.testing.assert_close(t, s.detach())
