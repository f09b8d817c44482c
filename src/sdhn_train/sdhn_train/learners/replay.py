"""Episode replay for the value-mixing learners (QMIX, HGCN-MIX).

``EpisodeAssembler`` cuts the trainer's fixed-length rollouts (T steps x B auto-resetting
environments) back into whole episodes; ``EpisodeBuffer`` stores them, padded to the episode limit
L, in a ring of ``capacity`` episodes. An episode of length l keeps l + 1 observations/states (the
last one is the env's ``final_obs``/``final_state``, used to bootstrap a truncated episode) and a
flag for whether it terminated (no bootstrap) or was truncated. Observations and states are stored
as float16 to halve memory (maif-20: ~1.2 MB per 500-step episode).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sdhn_train.rollout import Rollout


class EpisodeBuffer:
    FIELDS = ("obs", "state", "actions", "rewards", "terminated", "length")

    def __init__(self, capacity: int, max_len: int, num_robots: int, obs_size: int,
                 state_size: int) -> None:
        self.capacity, self.max_len = capacity, max_len
        self.obs = np.zeros((capacity, max_len + 1, num_robots, obs_size), np.float16)
        self.state = np.zeros((capacity, max_len + 1, state_size), np.float16)
        self.actions = np.zeros((capacity, max_len, num_robots), np.int16)
        self.rewards = np.zeros((capacity, max_len), np.float32)
        self.terminated = np.zeros(capacity, bool)
        self.length = np.zeros(capacity, np.int32)
        self.size = 0  # episodes held
        self.next = 0  # slot written next

    def add(self, obs: npt.NDArray[np.float32], state: npt.NDArray[np.float32],
            actions: npt.NDArray[np.int64], rewards: npt.NDArray[np.float32],
            terminated: bool) -> None:
        """One episode: obs [l+1, N, D], state [l+1, S], actions [l, N], rewards [l]."""
        n = len(rewards)
        if n > self.max_len:
            raise ValueError(f"episode of {n} steps exceeds the buffer's limit {self.max_len}")
        k = self.next
        self.obs[k] = 0
        self.state[k] = 0
        self.actions[k] = 0
        self.rewards[k] = 0
        self.obs[k, : n + 1], self.state[k, : n + 1] = obs, state
        self.actions[k, :n], self.rewards[k, :n] = actions, rewards
        self.terminated[k], self.length[k] = terminated, n
        self.next = (k + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> dict[str, np.ndarray]:
        """``batch`` episodes (uniform, with replacement if fewer are held), trimmed to the
        longest sampled episode; time-major: obs [l+1, K, N, D], actions [l, K, N], ..."""
        idx = rng.integers(0, self.size, batch)
        t = int(self.length[idx].max())
        return {
            "obs": np.ascontiguousarray(self.obs[idx, : t + 1].swapaxes(0, 1), np.float32),
            "state": np.ascontiguousarray(self.state[idx, : t + 1].swapaxes(0, 1), np.float32),
            "actions": self.actions[idx, :t].swapaxes(0, 1).astype(np.int64),
            "rewards": np.ascontiguousarray(self.rewards[idx, :t].swapaxes(0, 1)),
            "terminated": self.terminated[idx], "length": self.length[idx],
        }

    def state_dict(self) -> tuple[dict[str, np.ndarray], dict[str, int]]:
        return ({f: getattr(self, f) for f in self.FIELDS},
                {"size": self.size, "next": self.next})

    def load_state_dict(self, arrays: dict[str, np.ndarray], values: dict[str, int]) -> None:
        for f in self.FIELDS:
            getattr(self, f)[...] = arrays[f]
        self.size, self.next = int(values["size"]), int(values["next"])


class EpisodeAssembler:
    """Per-environment episodes in progress, completed from consecutive rollouts."""

    def __init__(self, num_envs: int, max_len: int, num_robots: int, obs_size: int,
                 state_size: int) -> None:
        self.max_len = max_len
        self.obs = np.zeros((num_envs, max_len + 1, num_robots, obs_size), np.float32)
        self.state = np.zeros((num_envs, max_len + 1, state_size), np.float32)
        self.actions = np.zeros((num_envs, max_len, num_robots), np.int64)
        self.rewards = np.zeros((num_envs, max_len), np.float32)
        self.length = np.zeros(num_envs, np.int64)

    def add_rollout(self, r: Rollout, buffer: EpisodeBuffer) -> int:
        """Append every step of ``r``; push each finished episode into ``buffer``. Returns the
        number of episodes pushed."""
        t_len, b_len, _ = r.shape
        done = r.done
        pushed = 0
        envs = np.arange(b_len)
        for t in range(t_len):
            pos = self.length
            if int(pos.max()) >= self.max_len:
                raise ValueError(f"an episode ran past {self.max_len} steps: set env.max_steps "
                                 "to the environment's episode limit")
            self.obs[envs, pos], self.state[envs, pos] = r.obs[t], r.state[t]
            self.actions[envs, pos], self.rewards[envs, pos] = r.actions[t], r.rewards[t]
            self.length += 1
            for b in np.flatnonzero(done[t]):
                n = int(self.length[b])
                self.obs[b, n], self.state[b, n] = r.final_obs[t, b], r.final_state[t, b]
                buffer.add(self.obs[b, : n + 1], self.state[b, : n + 1], self.actions[b, :n],
                           self.rewards[b, :n], bool(r.terminated[t, b]))
                self.length[b] = 0
                pushed += 1
        return pushed

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"obs": self.obs, "state": self.state, "actions": self.actions,
                "rewards": self.rewards, "length": self.length}

    def load_state_dict(self, arrays: dict[str, np.ndarray]) -> None:
        for k, v in self.state_dict().items():
            v[...] = arrays[k]
