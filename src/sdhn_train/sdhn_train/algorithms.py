"""Algorithms behind one small interface (BenchMARL-style): only the critic differs.

    algo = get_algorithm("sdhn")                        # ConfigError for unknown names
    learner = build_learner(cfg, EnvInfo.of(env), seed)  # actor + algo.build_critic + PPOLearner

Adding a baseline = one class with ``name``, defaults and ``build_critic``, listed in ALGORITHMS.
An algorithm whose learner is not PPO (QMIX, HGCN-MIX: off-policy value mixing) defines
``build_learner`` instead; ``build_learner`` below hands over to it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorSpec
from sdhn_train.baselines.dicg import DICG
from sdhn_train.baselines.hgcn_mix import HGCNMIX
from sdhn_train.baselines.qmix import QMIX, ValueMixingLearner
from sdhn_train.config import ALGO_NAMES, Config, ConfigError, PPOConfig
from sdhn_train.critics import Critic, MLPCritic, SDHNCritic
from sdhn_train.hypergraph import Noise
from sdhn_train.ppo import PPOLearner


@dataclass(frozen=True)
class EnvInfo:
    """What networks need to know about an environment."""

    obs_size: int
    state_size: int
    num_robots: int
    num_actions: int
    max_steps: int = 500  # episode limit (the size of QMIX's replay episodes)
    features: str = "identity"  # input transform of the raw obs (obs_size = its output size)
    raw_obs_size: int = 0  # length of the raw observation (0 = obs_size)

    @classmethod
    def of(cls, env: Any) -> EnvInfo:
        """Of a ``BatchedEnv``, or of an ``env_features.FeatureEnv`` (features, raw size)."""
        return cls(env.obs_size, env.state_size, env.num_robots, env.num_actions,
                   env.max_steps, getattr(env, "features", "identity"),
                   getattr(env, "raw_obs_size", env.obs_size))


class Algorithm(Protocol):
    name: ClassVar[str]
    default_lr: ClassVar[float]
    default_target_tau: ClassVar[float]

    def build_critic(self, cfg: Config, info: EnvInfo) -> Critic: ...


class SDHN:
    """SDHN: stochastic-hypergraph HGCN critic with skewness loss and a target critic."""

    name: ClassVar[str] = "sdhn"
    default_lr: ClassVar[float] = 6e-4
    default_target_tau: ClassVar[float] = 0.01

    def build_critic(self, cfg: Config, info: EnvInfo) -> Critic:
        s = cfg.sdhn
        noise: Noise = "gumbel_paper" if s.noise == "gumbel_paper" else "logistic"
        return SDHNCritic(
            info.obs_size, info.state_size, info.num_robots, num_hyperedges=s.num_hyperedges,
            generator_hidden=s.generator_hidden, generator_layers=s.generator_layers,
            hgcn_hidden=s.hgcn_hidden, hgcn_layers=s.hgcn_layers, state_hidden=s.state_hidden,
            tau=s.tau, noise=noise, stochastic_hyperedges=s.stochastic_hyperedges,
            skew_loss=s.skew_loss, lambda_sk=s.lambda_sk, lambda_cb=s.lambda_cb)


class MAPPO:
    """MAPPO: same actor, MLP critic on the global state, no target critic."""

    name: ClassVar[str] = "mappo"
    default_lr: ClassVar[float] = 3e-4
    default_target_tau: ClassVar[float] = 1.0

    def build_critic(self, cfg: Config, info: EnvInfo) -> Critic:
        return MLPCritic(info.state_size, info.num_robots, tuple(cfg.mappo.critic_hidden))


ALGORITHMS: dict[str, type[SDHN] | type[MAPPO] | type[QMIX] | type[DICG] | type[HGCNMIX]] = {
    a.name: a for a in (SDHN, MAPPO, QMIX, DICG, HGCNMIX)}
assert tuple(ALGORITHMS) == ALGO_NAMES


def get_algorithm(name: str) -> SDHN | MAPPO | QMIX | DICG | HGCNMIX:
    if name not in ALGORITHMS:
        raise ConfigError(f"algo.name = {name!r} is invalid; allowed: {', '.join(ALGORITHMS)}")
    return ALGORITHMS[name]()


def resolve_ppo(cfg: PPOConfig, algo: Algorithm) -> PPOConfig:
    """Fill the algorithm-dependent defaults (null lr / critic_lr / target_tau)."""
    lr = cfg.lr if cfg.lr is not None else algo.default_lr
    return dataclasses.replace(
        cfg, lr=lr, critic_lr=cfg.critic_lr if cfg.critic_lr is not None else lr,
        target_tau=cfg.target_tau if cfg.target_tau is not None else algo.default_target_tau)


def actor_spec(cfg: Config, info: EnvInfo) -> ActorSpec:
    return ActorSpec(obs_size=info.raw_obs_size or info.obs_size, features=info.features,
                     num_actions=info.num_actions,
                     hidden_sizes=tuple(cfg.actor.hidden_sizes), gru_hidden=cfg.actor.gru_hidden,
                     use_robot_id=cfg.actor.use_robot_id,
                     num_robots=info.num_robots if cfg.actor.use_robot_id else 0)


def build_learner(cfg: Config, info: EnvInfo,
                  rng: np.random.Generator) -> PPOLearner | ValueMixingLearner:
    """Actor + the algorithm's critic + the shared PPO learner (call after seeding torch), or the
    algorithm's own learner where it has one (QMIX, HGCN-MIX)."""
    algo = get_algorithm(cfg.algo.name)
    if isinstance(algo, QMIX | HGCNMIX):
        return algo.build_learner(cfg, info, rng)
    actor = Actor(actor_spec(cfg, info))
    critic = algo.build_critic(cfg, info)
    return PPOLearner(actor, critic, resolve_ppo(cfg.ppo, algo), rng)
