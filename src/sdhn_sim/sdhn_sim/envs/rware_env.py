"""RWARE adapter: B copies of the real ``rware`` 2.0.0 Gymnasium env behind the batched API.

Tasks (choice documented in the README of envs, ``__init__``): ``rware-N`` is rware's registered
``rware-small-{N}ag-v2`` — 2 shelf rows x 3 shelf columns, column height 8 (a 20 x 10 grid),
sensor range 1, request queue N ("normal" difficulty), individual rewards, 500 steps. The SDHN
authors' config uses ``rware:rware-small-3ag-v2`` with a 500-step limit; 6 and 9 robots keep the
same warehouse. Size and difficulty are overridable.

rware 2.0.0 reports the 500-step limit as ``terminated=True, truncated=False``; the adapter
reports it as what it is, a truncation (``terminated=False, truncated=True``), so learners
bootstrap. RWARE has no success notion: ``EpisodeStats.makespan`` is None, ``completed`` False,
``collisions`` 0 and ``formation_error`` 0. ``deliveries`` counts the requested shelves delivered:
the registered tasks pay rware's *individual* reward, exactly +1 to one robot per delivery and
nothing else, so the count is the number of +1 payments (and equals the return). It is not read
from the request queue: a shelf newly requested while it stands on the other goal is delivered
twice in one step but replaces one queue slot (seen on rware-9).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from .api import EpisodeStats, FloatArray, StepResult

RWARE_SIZES = ("tiny", "small", "medium", "large")
RWARE_DIFFICULTIES = {"easy": "-easy", "normal": "", "hard": "-hard"}
NUM_ACTIONS = 5  # noop, forward, left, right, toggle_load


def rware_env_id(num_robots: int, size: str = "small", difficulty: str = "normal") -> str:
    if size not in RWARE_SIZES:
        raise ValueError(f"size must be one of {list(RWARE_SIZES)}, got {size!r}")
    if difficulty not in RWARE_DIFFICULTIES:
        raise ValueError(
            f"difficulty must be one of {list(RWARE_DIFFICULTIES)}, got {difficulty!r}"
        )
    if not 1 <= int(num_robots) <= 19:
        raise ValueError(f"num_robots must be in [1, 19] (rware registers 1..19), got {num_robots}")
    return f"rware-{size}-{int(num_robots)}ag{RWARE_DIFFICULTIES[difficulty]}-v2"


def check_batch_args(num_envs: int, max_steps: int, seed: int) -> None:
    """The arguments both RWARE backends share, refused the same way (ValueError)."""
    if int(num_envs) < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    if int(max_steps) < 1:
        raise ValueError(f"max_steps must be an int >= 1, got {max_steps!r}")
    if int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")


def first_reset_seeds(seed: int, num_envs: int) -> list[int | None]:
    """The seed of each copy's next reset in a batch seeded ``seed``: copy ``b`` starts from
    ``seed + b``; after that first reset (None) it continues its own generator."""
    if int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    return [int(seed) + b for b in range(int(num_envs))]


def checked_actions(actions: npt.ArrayLike, num_envs: int, num_robots: int) -> npt.NDArray[Any]:
    """The [B, N] integer actions both RWARE backends take, refused the same way (ValueError).
    The range [0, NUM_ACTIONS) each backend checks in its cheapest form and refuses with
    ``action_range_error``."""
    a = np.asarray(actions)
    if a.shape != (num_envs, num_robots):
        raise ValueError(f"actions must have shape {(num_envs, num_robots)}, got {a.shape}")
    if a.dtype.kind not in "iu":
        raise ValueError(f"actions must be integers in [0, {NUM_ACTIONS}), got {a.dtype}")
    return a


def action_range_error(a: npt.NDArray[Any]) -> ValueError:
    return ValueError(f"actions must be in [0, {NUM_ACTIONS}), got {a.min()}..{a.max()}")


def make_rware_gym(env_id: str, max_steps: int) -> Any:
    """The raw gymnasium env as rware registers it (``gym.make``), with our step limit."""
    import gymnasium as gym
    import rware  # noqa: F401  (registers the rware-* ids)

    return gym.make(env_id, max_steps=max_steps)


class RwareEnv:
    """B rware environments stepped in a loop (implements ``BatchedEnv``).

    Copy ``b`` of a batch seeded ``s`` is first reset with seed ``s + b``; its later episodes
    continue that generator (``reset(seed=None)``), exactly as a raw rware loop would.
    """

    num_actions = NUM_ACTIONS

    def __init__(
        self,
        num_robots: int,
        num_envs: int = 1,
        seed: int = 0,
        *,
        size: str = "small",
        difficulty: str = "normal",
        max_steps: int = 500,
        name: str | None = None,
    ) -> None:
        check_batch_args(num_envs, max_steps, seed)
        self.env_id = rware_env_id(num_robots, size, difficulty)
        self.name = name or self.env_id
        self.num_envs = int(num_envs)
        self.num_robots = int(num_robots)
        self.max_steps = int(max_steps)
        self._envs = [make_rware_gym(self.env_id, self.max_steps) for _ in range(self.num_envs)]
        # step the Warehouse itself: the gymnasium wrappers only add per-step checks
        self._raw = [e.unwrapped for e in self._envs]
        if self._raw[0].reward_type.name != "INDIVIDUAL":  # deliveries are counted from it
            raise ValueError(f"{self.env_id}: expected rware's individual reward, got "
                             f"{self._raw[0].reward_type.name}")
        space = self._envs[0].observation_space
        self.obs_size = int(space[0].shape[0])
        self.state_size = self.num_robots * self.obs_size
        self._pending_seed = first_reset_seeds(seed, self.num_envs)
        self._t = [0] * self.num_envs
        self._ret = [0.0] * self.num_envs
        self._deliveries = [0] * self.num_envs
        self._started = False
        self.robot_rewards: FloatArray = np.zeros((self.num_envs, self.num_robots), np.float32)

    def _reset_one(self, b: int) -> tuple[npt.NDArray[np.float32], ...]:
        seed = self._pending_seed[b]
        self._pending_seed[b] = None
        obs, _ = self._raw[b].reset(seed=seed)
        self._t[b] = 0
        self._ret[b] = 0.0
        self._deliveries[b] = 0
        return tuple(obs)

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        if seed is not None:
            self._pending_seed = first_reset_seeds(seed, self.num_envs)
        obs = np.empty((self.num_envs, self.num_robots, self.obs_size), dtype=np.float32)
        for b in range(self.num_envs):
            obs[b] = self._reset_one(b)
        self._started = True
        return obs, obs.reshape(self.num_envs, -1)

    def step(self, actions: npt.ArrayLike) -> StepResult:
        # The per-step work around rware's own step is kept to plain Python on small lists and a
        # handful of NumPy calls: rware-3 steps in ~0.5 ms, so each NumPy call here is ~0.3 %.
        if not self._started:
            raise RuntimeError("call reset() before step()")
        nb, n = self.num_envs, self.num_robots
        a = checked_actions(actions, nb, n)
        acts: list[list[int]] = a.tolist()  # rware steps on lists: the range check reads them
        if min(map(min, acts)) < 0 or max(map(max, acts)) >= NUM_ACTIONS:
            raise action_range_error(a)
        obs = np.empty((nb, n, self.obs_size), dtype=np.float32)
        rewards: list[list[float]] = []
        team: list[float] = []
        term = [False] * nb
        trunc = [False] * nb
        done: list[int] = []
        limit = self.max_steps
        for b, env in enumerate(self._raw):
            o, r, te, tr, _ = env.step(acts[b])
            ob = obs[b]
            for i in range(n):
                ob[i] = o[i]
            rewards.append(r)
            tr_b = sum(r)
            team.append(tr_b)
            self._t[b] += 1
            self._ret[b] += tr_b
            self._deliveries[b] += round(tr_b)  # one +1 payment per delivery
            if te or tr:
                # rware 2.0.0 flags its own step limit as terminated: report it as truncation
                trunc[b] = bool(tr) or env._cur_steps >= limit
                term[b] = not trunc[b]
                done.append(b)
        self.robot_rewards = np.array(rewards, dtype=np.float32)
        final_obs = obs
        episodes: list[EpisodeStats] = []
        if done:
            final_obs = obs.copy()
            for b in done:
                episodes.append(
                    EpisodeStats(
                        env_index=b,
                        episode_return=float(self._ret[b]),
                        length=self._t[b],
                        makespan=None,
                        completed=False,
                        collisions=0,
                        formation_error=0.0,
                        deliveries=self._deliveries[b],
                    )
                )
                obs[b] = self._reset_one(b)
        return StepResult(
            obs=obs,
            state=obs.reshape(nb, -1),
            reward=np.array(team, dtype=np.float32),
            terminated=np.array(term),
            truncated=np.array(trunc),
            final_obs=final_obs,
            final_state=final_obs.reshape(nb, -1),
            episodes=episodes,
        )

    @property
    def warehouses(self) -> list[Any]:
        """The B raw rware ``Warehouse`` objects, read-only by convention: what a centralised
        scripted baseline (``rware_scripted.ScriptedPolicy``) plans from."""
        return list(self._raw)

    @property
    def positions(self) -> npt.NDArray[np.int64]:
        """[B, N, 2] (x, y) of every robot, read from the rware warehouses."""
        return np.array([[[a.x, a.y] for a in raw.agents] for raw in self._raw],
                        dtype=np.int64).reshape(len(self._raw), self.num_robots, 2)

    def close(self) -> None:
        for e in self._envs:
            e.close()
