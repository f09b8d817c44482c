"""Single-environment view of a ``BatchedEnv`` with ``num_envs == 1``.

Gymnasium / PettingZoo-parallel style: ``reset(seed) -> (obs [N, D], state [S])`` and
``step(actions [N]) -> (obs, state, reward, terminated, truncated, info)``. Unlike the batched
core it does not auto-reset in front of the caller: after a finished episode ``step`` returns the
episode's last observation and the caller must call ``reset()``, which then returns the next
episode (the one the batched core already drew, so the instance stream stays deterministic).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from .api import BatchedEnv, EpisodeStats, FloatArray, reward_name
from .maif import MaifEnv, MaifWorld
from .rware_batched import RwareBatchedEnv
from .rware_env import RwareEnv


@dataclass(frozen=True)
class SingleStep:
    """What ``SingleEnv.step`` returns; unpacks like Gymnasium's 5-tuple plus ``state``."""

    obs: FloatArray  # [N, D]
    state: FloatArray  # [S]
    reward: float  # team reward
    terminated: bool
    truncated: bool
    info: dict[str, Any] = field(default_factory=dict)

    def __iter__(self) -> Any:
        return iter((self.obs, self.state, self.reward, self.terminated, self.truncated, self.info))


class SingleEnv:
    """One environment: the simulator node and Gymnasium-style loops use this."""

    def __init__(self, env: BatchedEnv) -> None:
        if env.num_envs != 1:
            raise ValueError(f"SingleEnv needs num_envs == 1, got {env.num_envs}")
        self.env = env
        self.name = env.name
        self.num_robots = env.num_robots
        self.obs_size = env.obs_size
        self.state_size = env.state_size
        self.num_actions = env.num_actions
        self.max_steps = env.max_steps
        self.reward_name = reward_name(env)
        self._next: tuple[FloatArray, FloatArray] | None = None
        self._final_world: MaifWorld | None = None
        self._started = False

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        """Start an episode; returns (obs [N, D], state [S])."""
        if seed is None and self._next is not None:
            obs, state = self._next
        else:
            obs, state = self.env.reset(seed)
            obs, state = obs[0], state[0]
        self._next = None
        self._final_world = None
        self._started = True
        return obs, state

    def step(self, actions: npt.ArrayLike) -> SingleStep:
        """Apply int actions [N]. ``info`` holds ``episode`` (EpisodeStats) on the last step and,
        for MAIF, ``robot_rewards`` [N] and ``robot_collisions`` [N]."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self._next is not None:
            raise RuntimeError("the episode has ended: call reset() before step()")
        a = np.asarray(actions)
        if a.shape != (self.num_robots,):
            raise ValueError(f"actions must have shape ({self.num_robots},), got {a.shape}")
        res = self.env.step(a[None])
        info: dict[str, Any] = {}
        if isinstance(self.env, MaifEnv):
            info["robot_rewards"] = self.env.robot_rewards[0]
            info["robot_collisions"] = self.env.robot_collisions[0]
        terminated, truncated = bool(res.terminated[0]), bool(res.truncated[0])
        if terminated or truncated:
            ep: EpisodeStats = res.episodes[0]
            info["episode"] = ep
            self._next = (res.obs[0], res.state[0])
            if isinstance(self.env, MaifEnv):
                self._final_world = self.env.final_worlds.get(0)
        return SingleStep(
            res.final_obs[0], res.final_state[0], float(res.reward[0]), terminated, truncated, info
        )

    # ------------------------------------------------------------------ world access (MAIF)
    def world(self) -> MaifWorld:
        """Positions, goals and obstacles of the state the caller last saw (MAIF only)."""
        if not isinstance(self.env, MaifEnv):
            raise NotImplementedError(f"{self.name}: world() is only available for MAIF")
        return self._final_world if self._final_world is not None else self.env.world(0)

    @property
    def positions(self) -> npt.NDArray[np.int64]:
        """[N, 2] robot cells (x, y) of the state the caller last saw (MAIF and RWARE)."""
        if isinstance(self.env, RwareEnv | RwareBatchedEnv):
            return self.env.positions[0]
        return self.world().positions

    @property
    def instance_id(self) -> int:
        """The MAIF instance of the current episode; -1 for worlds without numbered instances."""
        return self.world().instance_id if isinstance(self.env, MaifEnv) else -1

    @property
    def goals(self) -> npt.NDArray[np.int64]:
        return self.world().goals

    @property
    def obstacles(self) -> npt.NDArray[np.bool_]:
        return self.world().obstacles

    def render_rgb(self, cell_px: int = 8) -> npt.NDArray[np.uint8]:
        return self.world().render_rgb(cell_px)
