"""What an algorithm is (one small class behind one interface, BenchMARL-style) and what it reads
of the training configuration."""

from __future__ import annotations

from typing import Protocol, TypeVar

import numpy as np

from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.learners.ppo import PPOConfig
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
