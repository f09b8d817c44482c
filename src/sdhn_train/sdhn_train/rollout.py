"""The rollout: plain NumPy arrays handed to ``learner.update``.

Filled either by the vectorised in-process collector (``sdhn_train.collector``) or by a ROS trainer
node assembling messages (B = 1). Time-major: T steps x B environments x N robots.

Conventions
- ``obs[t]``/``state[t]`` are what the actors and critic saw before acting at step t.
- ``final_obs[t]``/``final_state[t]`` are the observation/state *after* step t in the same episode
  (the env's ``final_obs``; equal to ``obs[t+1]`` unless the episode ended at t). They are what
  the learner bootstraps from.
- ``terminated[t]``/``truncated[t]`` refer to step t; a new episode starts at t+1 where either is
  set, and the recurrent hidden states are zeroed there.
- ``actor_h0``/``critic_h0`` are the hidden states before step 0 (already zeroed where step 0
  starts an episode). ``critic_h0`` has the critic's own shape (``critic.initial_state(B)``);
  ``None`` means zeros.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]


@dataclass
class Rollout:
    obs: F32  # [T, B, N, D]
    state: F32  # [T, B, S]
    actions: npt.NDArray[np.int64]  # [T, B, N]
    log_probs: F32  # [T, B, N] behaviour policy's log-prob of the action taken
    rewards: F32  # [T, B] team reward
    terminated: npt.NDArray[np.bool_]  # [T, B]
    truncated: npt.NDArray[np.bool_]  # [T, B]
    final_obs: F32  # [T, B, N, D]
    final_state: F32  # [T, B, S]
    actor_h0: F32  # [B, N, H]
    critic_h0: F32 | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        t, b, n = self.actions.shape
        return t, b, n

    def validate(self) -> None:
        """Raise ValueError naming the first field whose shape disagrees with (T, B, N)."""
        t, b, n = self.shape
        d = self.obs.shape[-1]
        s = self.state.shape[-1]
        expected = {
            "obs": (t, b, n, d), "state": (t, b, s), "log_probs": (t, b, n),
            "rewards": (t, b), "terminated": (t, b), "truncated": (t, b),
            "final_obs": (t, b, n, d), "final_state": (t, b, s),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if tuple(got) != shape:
                raise ValueError(f"rollout.{name} has shape {tuple(got)}, expected {shape}")
        if self.actor_h0.shape[:2] != (b, n):
            raise ValueError(
                f"rollout.actor_h0 has shape {self.actor_h0.shape}, expected ({b}, {n}, H)")

    @property
    def done(self) -> npt.NDArray[np.bool_]:
        return self.terminated | self.truncated

    def resets(self) -> npt.NDArray[np.bool_]:
        """[T, B]: True where the hidden state is zeroed before step t (t >= 1 after a done)."""
        r = np.zeros_like(self.terminated)
        r[1:] = self.done[:-1]
        return r
