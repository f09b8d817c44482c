"""What networks need to know about an environment, and the actor architecture built from it."""

from __future__ import annotations

from dataclasses import dataclass

from sdhn_policy.weights import ActorSpec
from sdhn_sim.envs.api import BatchedEnv
from sdhn_train.sections import ActorConfig


@dataclass(frozen=True)
class EnvInfo:
    obs_size: int
    state_size: int
    num_robots: int
    num_actions: int
    max_steps: int = 500  # episode limit (the size of QMIX's replay episodes)
    features: str = "identity"  # input transform of the raw obs (obs_size = its output size)
    raw_obs_size: int = 0  # length of the raw observation (0 = obs_size)

    @classmethod
    def of(cls, env: BatchedEnv) -> EnvInfo:
        """Of a ``BatchedEnv``, or of an ``env_features.FeatureEnv`` (features, raw size)."""
        return cls(env.obs_size, env.state_size, env.num_robots, env.num_actions,
                   env.max_steps, getattr(env, "features", "identity"),
                   getattr(env, "raw_obs_size", env.obs_size))


def actor_spec(cfg: ActorConfig, info: EnvInfo) -> ActorSpec:
    """The shared decentralised actor (PPO's policy, the value-mixing learners' agent net)."""
    return ActorSpec(obs_size=info.raw_obs_size or info.obs_size, features=info.features,
                     num_actions=info.num_actions,
                     hidden_sizes=tuple(cfg.hidden_sizes), gru_hidden=cfg.gru_hidden,
                     use_robot_id=cfg.use_robot_id,
                     num_robots=info.num_robots if cfg.use_robot_id else 0)
