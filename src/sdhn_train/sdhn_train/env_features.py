"""The environment as the learners see it: named reward, and per-robot input features.

    env = make_training_env(cfg, factory, num_envs, seed)     # FeatureEnv for MAIF
    overrides = env_overrides(cfg)                             # {"max_steps": .., "reward": ..}

``FeatureEnv`` wraps a ``BatchedEnv`` and implements the same protocol, with every observation
replaced by ``sdhn_policy.features`` of it (obs, final_obs) and the state by the concatenation of
the N robots' features (state, final_state). The actor and the critic therefore both see the
features; the exported actor records the transform's name and applies it to raw observations
itself (``ActorRuntime``), so deployed actors keep receiving raw observations.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_policy.features import IDENTITY, default_features, feature_size, get_transform
from sdhn_sim.envs.api import BatchedEnv, FloatArray, StepResult
from sdhn_sim.envs.conditions import ConditionedEnv
from sdhn_train.config import Config, train_conditions
from sdhn_train.transitions import AssembledRollout


def resolve_features(cfg: Config) -> str:
    """``env.features`` with ``auto`` replaced by the environment's default transform."""
    f = cfg.env.features
    return default_features(cfg.env.name) if f == "auto" else f


def env_overrides(cfg: Config, **extra: Any) -> dict[str, Any]:
    """The ``make_env`` overrides a config asks for (the reward only for MAIF)."""
    out: dict[str, Any] = {}
    if cfg.env.max_steps is not None:
        out["max_steps"] = cfg.env.max_steps
    if cfg.env.name.startswith("maif"):
        out["reward"] = cfg.env.reward
        if cfg.env.instance_set != "train":
            out["instance_set"] = cfg.env.instance_set
    out.update(extra)
    return out


class FeatureEnv:
    """A ``BatchedEnv`` whose observations are features of the wrapped env's observations."""

    def __init__(self, env: BatchedEnv, features: str) -> None:
        self.inner_env = env
        self.features = features
        self._fn = get_transform(features)
        self.raw_obs_size = env.obs_size
        self.name = env.name
        self.num_envs = env.num_envs
        self.num_robots = env.num_robots
        self.num_actions = env.num_actions
        self.max_steps = env.max_steps
        self.obs_size = feature_size(features, env.obs_size)
        self.state_size = env.num_robots * self.obs_size

    def _both(self, obs: FloatArray) -> tuple[FloatArray, FloatArray]:
        f = self._fn(obs)
        return f, f.reshape(f.shape[0], -1)

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        obs, _ = self.inner_env.reset(seed=seed)
        return self._both(obs)

    def step(self, actions: npt.ArrayLike) -> StepResult:
        res = self.inner_env.step(actions)
        obs, state = self._both(res.obs)
        done = res.terminated | res.truncated
        if done.any():
            final_obs, final_state = self._both(res.final_obs)
        else:
            final_obs, final_state = obs, state
        return StepResult(obs=obs, state=state, reward=res.reward, terminated=res.terminated,
                          truncated=res.truncated, final_obs=final_obs, final_state=final_state,
                          episodes=res.episodes)

    def __getattr__(self, name: str) -> Any:  # reward_name, positions, world(), ... of the env
        if name == "inner_env":
            raise AttributeError(name)
        return getattr(self.inner_env, name)


def wrap_features(env: BatchedEnv, features: str) -> BatchedEnv:
    """``env`` itself for ``identity`` (keeps RWARE's own global state), else a FeatureEnv."""
    return env if features == IDENTITY else FeatureEnv(env, features)


def unwrap(env: Any) -> Any:
    """The innermost environment (for checkpoints, which snapshot its arrays)."""
    while isinstance(env, FeatureEnv | ConditionedEnv):
        env = env.inner_env
    return env


def conditioned(env: Any) -> ConditionedEnv | None:
    """The ``ConditionedEnv`` layer of a training env (``train.conditions``), if it has one."""
    while isinstance(env, FeatureEnv | ConditionedEnv):
        if isinstance(env, ConditionedEnv):
            return env
        env = env.inner_env
    return None


def featurize_obs(features: str, obs: npt.NDArray[np.float32]
                  ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Raw obs [..., N, D] -> (features [..., N, F], state [..., N * F])."""
    f = get_transform(features)(obs)
    return f, f.reshape(*f.shape[:-2], f.shape[-2] * f.shape[-1])  # also for 0 steps


EnvFactory = Callable[..., BatchedEnv]


def make_training_env(cfg: Config, factory: EnvFactory, num_envs: int, seed: int, *,
                      conditions: bool = True, **extra: Any) -> BatchedEnv:
    """``factory(name, num_envs, seed, **overrides)`` under the config's conditions
    (``train.conditions``: the robots' observations and actions pass through the condition
    model, seeded ``seed`` unless the block names one; ``conditions=False``: the ideal world,
    as evaluation plays), wrapped in the config's features."""
    env = factory(cfg.env.name, num_envs, seed, **env_overrides(cfg, **extra))
    cond = train_conditions(cfg)
    if conditions and not cond.ideal:
        env = ConditionedEnv(env, cond, seed=seed)
    return wrap_features(env, resolve_features(cfg))


def featurize_assembled(a: AssembledRollout, features: str) -> AssembledRollout:
    """A ROS-assembled rollout (raw observations from the messages) in the learner's features."""
    if features == IDENTITY:
        return a
    r = a.rollout
    obs, state = featurize_obs(features, r.obs)
    final_obs, final_state = featurize_obs(features, r.final_obs)
    prefix_obs, prefix_state = featurize_obs(features, a.prefix_obs)
    rollout = dataclasses.replace(r, obs=obs, state=state, final_obs=final_obs,
                                  final_state=final_state)
    return dataclasses.replace(a, rollout=rollout, prefix_obs=prefix_obs,
                               prefix_state=prefix_state)
