"""The one interface every environment exposes: B environments x N robots stepped at once.

Shapes use B = ``num_envs``, N = ``num_robots``, D = ``obs_size``, S = ``state_size``.
Environments auto-reset: when environment b finishes at a step, that step's ``obs[b]``/``state[b]``
already belong to the next episode, and the last observation of the finished episode is kept in
``final_obs[b]``/``final_state[b]`` so a learner can bootstrap a truncated episode correctly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class EpisodeStats:
    """Metrics of one finished episode of one environment in the batch."""

    env_index: int
    episode_return: float  # sum of team rewards over the episode
    length: int  # steps taken
    makespan: int | None  # steps until every robot was on its goal; None = not completed (NC)
    completed: bool  # every robot reached its goal before the step limit
    collisions: int  # robot-collision events summed over robots and steps
    formation_error: float  # mean per-step formation error (0 where the env has no formation)
    deliveries: int | None = None  # RWARE: requested shelves delivered; None elsewhere


@dataclass(frozen=True)
class StepResult:
    """What ``BatchedEnv.step`` returns."""

    obs: FloatArray  # [B, N, D] (next episode's first obs where an env finished)
    state: FloatArray  # [B, S]
    reward: FloatArray  # [B] team reward of this step
    terminated: BoolArray  # [B] the task ended (e.g. every robot on its goal)
    truncated: BoolArray  # [B] the step limit ended the episode
    final_obs: FloatArray  # [B, N, D] last obs of the finished episode (== obs where not done)
    final_state: FloatArray  # [B, S]
    episodes: list[EpisodeStats] = field(default_factory=list)  # one per env that finished


@runtime_checkable
class BatchedEnv(Protocol):
    """B environments x N robots, NumPy in and out, deterministic for a given seed."""

    name: str
    num_envs: int
    num_robots: int
    obs_size: int
    state_size: int
    num_actions: int
    max_steps: int

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        """Start a new episode in every environment; returns (obs [B,N,D], state [B,S])."""
        ...

    def step(self, actions: npt.ArrayLike) -> StepResult:
        """Apply int actions [B, N]; out-of-range actions raise ValueError."""
        ...


def reward_name(env: object) -> str:
    """The name of the reward an environment pays (MAIF: ``corrected``/``reference``; ``env``
    for environments with a single, built-in reward)."""
    return str(getattr(env, "reward_name", "env"))
