"""What an algorithm is (one small class behind one interface, BenchMARL-style) and what it reads
of the training configuration."""

from __future__ import annotations

from typing import Protocol, TypeVar

import numpy as np

from sdhn_policy.actor_torch import Actor
from sdhn_train.envinfo import EnvInfo, actor_spec
from sdhn_train.learners.base import Learner
from sdhn_train.learners.ppo import Critic, PPOConfig, PPOLearner, resolve_ppo
from sdhn_train.sections import ActorConfig, EnvConfig, Section

SectionT = TypeVar("SectionT")


class Settings(Protocol):
    """The parts of ``sdhn_train.config.Config`` an algorithm reads: the shared sections, and any
    algorithm's section by its class (``cfg.section(SDHNConfig)``)."""

    @property
    def env(self) -> EnvConfig: ...

    @property
    def actor(self) -> ActorConfig: ...

    @property
    def ppo(self) -> PPOConfig: ...

    def section(self, cls: type[SectionT]) -> SectionT: ...


class Algorithm(Protocol):
    """``name`` is also the name of its config section, whose dataclass is ``config``."""

    @property
    def name(self) -> str: ...

    @property
    def config(self) -> type[Section]: ...

    @property
    def data_parallel(self) -> bool:
        """Whether its learner runs as K data-parallel processes (``train.learner_processes``;
        the PPO learner all-reduces its gradients, the value-mixing learner does not)."""
        ...

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        """The networks and their learner (call after seeding torch)."""
        ...


def ppo_learner(cfg: Settings, info: EnvInfo, rng: np.random.Generator, critic: Critic, *,
                default_lr: float, default_target_tau: float) -> PPOLearner:
    """The shared actor + ``critic`` on the one PPO learner, the ``ppo`` section's null lr and
    target_tau filled with the algorithm's defaults (SDHN, MAPPO, DICG: only the critic
    differs)."""
    return PPOLearner(Actor(actor_spec(cfg.actor, info)), critic,
                      resolve_ppo(cfg.ppo, default_lr, default_target_tau), rng)
