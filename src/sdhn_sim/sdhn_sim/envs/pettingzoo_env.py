"""Every named environment as a PettingZoo ``ParallelEnv`` (and a Gymnasium joint-action env).

For MARL code that speaks PettingZoo (EPyMARL, BenchMARL, TorchRL, CleanRL-style loops)::

    from sdhn_sim.envs.pettingzoo_env import parallel_env
    env = parallel_env("maif-10", seed=0)
    obs, infos = env.reset(seed=1)                   # {"robot_0": obs [D], ...}
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)

Agents are ``robot_0 .. robot_{N-1}``; each observes only its own local observation (float32
[D], the vector the ROS simulator publishes) and picks a ``Discrete(A)`` action. ``state()`` is the
global state a centralised critic trains on. Rewards are per robot where the environment pays
them (MAIF's per-robot terms, RWARE's individual delivery reward); their sum is the team reward
the in-process trainer uses. When the episode ends every agent is terminated or truncated at once
and ``agents`` becomes empty, as PettingZoo's parallel API requires. ``infos[agent]["episode"]``
on the last step holds the episode's metrics, every one a number (TorchRL and BenchMARL keep
numeric leaves only): ``completed`` 1 or 0, ``makespan`` the steps until every robot was on its
goal or ``NOT_COMPLETED`` (-1) when the episode did not complete, ``deliveries`` RWARE's count or
``NOT_APPLICABLE`` (-1) elsewhere; :func:`episode_from_info` gives back the project's
``EpisodeStats`` (``None`` for "not completed").

TorchRL's ``PettingZooWrapper`` (and BenchMARL through it) builds its info spec from the infos of
``reset()`` and keeps only those keys, each a number; with ``flat_infos=True`` every infos dict,
at reset and at every step, holds the same flat keys ``episode_done`` (1 on the step that ends the
episode, else 0) and ``episode_<metric>`` for each metric above (the placeholders 0, and
``NOT_COMPLETED`` / ``NOT_APPLICABLE`` for makespan / deliveries, until the episode ends), and no
nested ``episode``.

``JointEnv`` is the same environment as one Gymnasium env (observation [N, D], a
``MultiDiscrete([A] * N)`` joint action, the team reward); ``register_gymnasium_envs()`` registers
it as ``sdhn/<name>-v0`` for every name of :func:`sdhn_sim.envs.registry.env_names`.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict
from typing import Any, ClassVar

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .api import EpisodeStats
from .maif import MaifEnv
from .registry import env_names, make_single_env
from .single import SingleEnv

GYM_NAMESPACE = "sdhn"
NOT_COMPLETED = -1  # infos' makespan of an episode that did not complete (EpisodeStats: None)
NOT_APPLICABLE = -1  # infos' deliveries in an environment without deliveries (MAIF)
MAIF_OBS_BOUNDS = (0.0, 2.0)  # coordinates in [0, 1]; window cells 0 free, 1 obstacle, 2 robot


def _obs_space(env: SingleEnv, shape: tuple[int, ...]) -> spaces.Box:
    low, high = MAIF_OBS_BOUNDS if isinstance(env.env, MaifEnv) else (-np.inf, np.inf)
    return spaces.Box(low=low, high=high, shape=shape, dtype=np.float32)


def _robot_rewards(env: SingleEnv, team_reward: float, info: dict[str, Any]) -> npt.NDArray[Any]:
    per_robot = info.get("robot_rewards", getattr(env.env, "robot_rewards", None))
    if per_robot is None:  # an env with a team reward only: every robot gets it
        return np.full(env.num_robots, team_reward, dtype=np.float32)
    return np.asarray(per_robot, dtype=np.float32).reshape(-1)[: env.num_robots]


class SdhnParallelEnv(ParallelEnv):
    """A named sdhn environment behind PettingZoo's parallel API (see the module docstring)."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "sdhn_parallel_v0", "render_modes": ["rgb_array"], "is_parallelizable": True}

    def __init__(self, name: str, seed: int = 0, render_mode: str | None = None,
                 flat_infos: bool = False, **overrides: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode: got {render_mode!r}; allowed: None, 'rgb_array'")
        self.env = make_single_env(name, seed=seed, **overrides)
        self.name = name
        self.render_mode = render_mode
        self.flat_infos = flat_infos  # TorchRL/BenchMARL: the same numeric keys every step
        self.possible_agents = [f"robot_{i}" for i in range(self.env.num_robots)]
        self.agents: list[str] = []
        self._obs_space = _obs_space(self.env, (self.env.obs_size,))
        self._act_space = spaces.Discrete(self.env.num_actions)
        self.state_space = spaces.Box(-np.inf, np.inf, (self.env.state_size,), np.float32)
        self._state: npt.NDArray[np.float32] = np.zeros(self.env.state_size, np.float32)

    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._act_space

    def _split(self, obs: npt.NDArray[np.float32]) -> dict[str, npt.NDArray[np.float32]]:
        return {a: np.array(obs[i], dtype=np.float32) for i, a in enumerate(self.possible_agents)}

    def reset(self, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        if options:  # none are defined; PettingZoo's API test passes some, so warn, not raise
            warnings.warn(f"reset options {sorted(map(str, options))[:5]} ignored: this "
                          "environment has none", UserWarning, stacklevel=2)
        obs, state = self.env.reset(seed)
        self._state = np.asarray(state, dtype=np.float32)
        self.agents = list(self.possible_agents)
        return self._split(obs), {a: self._infos(None) for a in self.agents}

    def _infos(self, episode: EpisodeStats | None) -> dict[str, Any]:
        """One agent's infos: ``{}`` or ``{"episode": ...}``; with flat_infos the flat keys."""
        if not self.flat_infos:
            return {} if episode is None else {"episode": episode_info(episode)}
        metrics = episode_info(episode if episode is not None else PLACEHOLDER)
        return {"episode_done": int(episode is not None),
                **{f"episode_{k}": v for k, v in metrics.items() if k != "env_index"}}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], ...]:
        if not self.agents:
            raise RuntimeError("the episode has ended: call reset() before step()")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"actions: missing for {missing}; every live agent acts each step")
        unknown = [str(a)[:40] for a in actions if a not in self.agents]
        if unknown:
            raise ValueError(f"actions: unknown agents {unknown[:5]}; allowed: {self.agents}")
        joint = np.array([check_action(a, actions[a], self.env.num_actions)
                          for a in self.possible_agents], dtype=np.int64)
        res = self.env.step(joint)
        self._state = np.asarray(res.state, dtype=np.float32)
        rewards = _robot_rewards(self.env, res.reward, res.info)
        episode = res.info.get("episode")
        infos = {a: self._infos(episode) for a in self.agents}
        out = (
            self._split(res.obs),
            {a: float(rewards[i]) for i, a in enumerate(self.possible_agents)},
            {a: res.terminated for a in self.agents},
            {a: res.truncated for a in self.agents},
            infos,
        )
        if res.terminated or res.truncated:
            self.agents = []
        return out

    def state(self) -> npt.NDArray[np.float32]:
        return self._state.copy()

    def render(self) -> npt.NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array":
            return None
        return self.env.render_rgb()

    def close(self) -> None:
        pass


def check_action(agent: str, value: Any, num_actions: int) -> int:
    """``value`` as an action index in [0, num_actions): a Python or NumPy integer (also a 0-d
    array), never a float, bool or string (2.7 was truncated to 2, "1" and True taken as 1);
    ValueError naming the agent and what is allowed."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
        raise ValueError(f"actions[{agent!r}]: {str(value)[:40]!r} of type "
                         f"{type(value).__name__}; allowed: an integer in 0 .. {num_actions - 1}")
    if not 0 <= value < num_actions:
        raise ValueError(f"actions[{agent!r}]: {value}; allowed: 0 .. {num_actions - 1}")
    return int(value)


# flat_infos' values before an episode has ended (makespan and deliveries: the sentinels)
PLACEHOLDER = EpisodeStats(env_index=0, episode_return=0.0, length=0, makespan=None,
                           completed=False, collisions=0, formation_error=0.0)


def episode_info(episode: EpisodeStats) -> dict[str, int | float]:
    """An episode's metrics with numbers only (see the module docstring for the sentinels)."""
    d = asdict(episode)
    d["completed"] = int(episode.completed)
    d["makespan"] = NOT_COMPLETED if episode.makespan is None else int(episode.makespan)
    d["deliveries"] = NOT_APPLICABLE if episode.deliveries is None else int(episode.deliveries)
    return d


def episode_from_info(info: dict[str, Any]) -> EpisodeStats:
    """The project's ``EpisodeStats`` of ``infos[agent]["episode"]`` (sentinels back to None)."""
    d = dict(info)
    d["completed"] = bool(d["completed"])
    d["makespan"] = None if d["makespan"] == NOT_COMPLETED else int(d["makespan"])
    d["deliveries"] = None if d["deliveries"] == NOT_APPLICABLE else int(d["deliveries"])
    return EpisodeStats(**d)


def parallel_env(name: str, seed: int = 0, render_mode: str | None = None,
                 **overrides: Any) -> SdhnParallelEnv:
    """``name`` (any of ``env_names()``, with the registry's overrides) as a ParallelEnv."""
    return SdhnParallelEnv(name, seed=seed, render_mode=render_mode, **overrides)


class JointEnv(gymnasium.Env):
    """The team as one Gymnasium env: observation [N, D], joint action, team reward."""

    metadata = {"render_modes": ["rgb_array"]}  # noqa: RUF012 (gymnasium.Env declares it so)

    def __init__(self, name: str, seed: int = 0, render_mode: str | None = None,
                 **overrides: Any) -> None:
        self.parallel = SdhnParallelEnv(name, seed=seed, render_mode=render_mode, **overrides)
        env = self.parallel.env
        self.render_mode = render_mode
        self.observation_space = _obs_space(env, (env.num_robots, env.obs_size))
        self.action_space = spaces.MultiDiscrete([env.num_actions] * env.num_robots)

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        obs, _ = self.parallel.reset(seed=seed, options=options)
        return np.stack(list(obs.values())), {"state": self.parallel.state()}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        agents = self.parallel.possible_agents
        joint = np.asarray(action, dtype=object if isinstance(action, list | tuple) else None)
        if joint.shape != (len(agents),):
            raise ValueError(f"action: shape {joint.shape}; allowed: ({len(agents)},) integers "
                             f"in 0 .. {self.parallel.env.num_actions - 1}")
        obs, rewards, term, trunc, infos = self.parallel.step(dict(zip(agents, joint,
                                                                       strict=True)))
        info = {"state": self.parallel.state(), "robot_rewards": np.array(list(rewards.values()))}
        info.update(infos[agents[0]])
        return (np.stack(list(obs.values())), float(sum(rewards.values())),
                bool(term[agents[0]]), bool(trunc[agents[0]]), info)

    def render(self) -> npt.NDArray[np.uint8] | None:
        return self.parallel.render()


def gym_id(name: str) -> str:
    return f"{GYM_NAMESPACE}/{name}-v0"


def register_gymnasium_envs() -> list[str]:
    """Register ``sdhn/<name>-v0`` for every environment name (idempotent); returns the ids."""
    ids = []
    for name in env_names():
        env_id = gym_id(name)
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=f"{__name__}:JointEnv", kwargs={"name": name})
        ids.append(env_id)
    return ids
