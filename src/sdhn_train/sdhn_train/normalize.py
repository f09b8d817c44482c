"""Running reward normalisation (``ppo.normalize_rewards``): divide team rewards by the running
standard deviation of the discounted return, as in CleanRL's / Gymnasium's ``NormalizeReward``.

The value targets then stay near unit scale whatever the reward's magnitude (MAIF's team returns
range from about -150 to +15), so the critic fits early instead of chasing large targets.
Logged returns are never normalised (they come from the environments' episode statistics).
The statistics are part of the trainer's checkpoint (``state``/``load_state``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sdhn_train.rollout import Rollout


class RunningMeanStd:
    """Mean and variance of a stream of scalars (parallel Welford / Chan et al.)."""

    def __init__(self) -> None:
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def update(self, x: npt.NDArray[np.float64]) -> None:
        b_mean, b_var, b_count = float(np.mean(x)), float(np.var(x)), x.size
        delta = b_mean - self.mean
        total = self.count + b_count
        self.mean += delta * b_count / total
        m2 = self.var * self.count + b_var * b_count + delta * delta * self.count * b_count / total
        self.var, self.count = m2 / total, total


class RewardNormalizer:
    """Scales a rollout's rewards by 1 / std(discounted return), tracked per environment."""

    def __init__(self, num_envs: int, gamma: float, eps: float = 1e-8) -> None:
        self.gamma, self.eps = gamma, eps
        self.returns = np.zeros(num_envs, dtype=np.float64)
        self.stats = RunningMeanStd()

    def __call__(self, rollout: Rollout) -> Rollout:
        rewards = rollout.rewards.astype(np.float64)
        done = rollout.done
        seen = np.empty_like(rewards)
        for t in range(rewards.shape[0]):
            self.returns = self.returns * self.gamma + rewards[t]
            seen[t] = self.returns
            self.returns[done[t]] = 0.0
        self.stats.update(seen.reshape(-1))
        scale = 1.0 / np.sqrt(self.stats.var + self.eps)
        rollout.rewards = (rewards * scale).astype(np.float32)
        return rollout

    def state(self) -> dict[str, npt.NDArray[np.float64]]:
        s = self.stats
        return {"returns": self.returns.copy(), "stats": np.array([s.mean, s.var, s.count])}

    def load_state(self, arrays: dict[str, npt.NDArray[np.float64]]) -> None:
        self.returns = np.asarray(arrays["returns"], dtype=np.float64).copy()
        self.stats.mean, self.stats.var, self.stats.count = (float(v) for v in arrays["stats"])
