"""Advantages and value targets (eqs. td_error, gae_advantage, v_target).

Time-major tensors: rewards [T, B], values/next_values [T, B, *] (e.g. * = N robots).
``next_values[t]`` is V(s^{t+1}; theta') of the *same* episode: where step t truncated the episode
it is the value of ``final_state[t]``, not of the next episode's first state. ``terminated[t]``
zeroes the bootstrap; ``done[t]`` (terminated or truncated) cuts the GAE sum.
"""

from __future__ import annotations

import torch
from torch import Tensor


def _expand(x: Tensor, like: Tensor) -> Tensor:
    return x.reshape(x.shape + (1,) * (like.dim() - x.dim())).to(like.dtype)


def td_errors(rewards: Tensor, values: Tensor, next_values: Tensor, terminated: Tensor,
              gamma: float) -> Tensor:
    """delta^t = r^t + gamma V(s^{t+1}; theta') - V(s^t; theta') (eq. td_error); the bootstrap is
    0 after a terminal step."""
    not_term = 1.0 - _expand(terminated, values)
    return _expand(rewards, values) + gamma * not_term * next_values - values


def gae_advantages(deltas: Tensor, done: Tensor, gamma: float, lam: float) -> Tensor:
    """A^t = sum_l (gamma lambda)^l delta^{t+l} within an episode (eq. gae_advantage), by the
    backward recursion A^t = delta^t + gamma lambda (1 - done^t) A^{t+1}."""
    cont = 1.0 - _expand(done, deltas)
    adv = torch.zeros_like(deltas)
    acc = torch.zeros_like(deltas[0])
    for t in range(deltas.shape[0] - 1, -1, -1):
        acc = deltas[t] + gamma * lam * cont[t] * acc
        adv[t] = acc
    return adv


def value_targets(advantages: Tensor, target_values: Tensor) -> Tensor:
    """V'^t = A^t + V(s^t; theta') (eq. v_target)."""
    return advantages + target_values
