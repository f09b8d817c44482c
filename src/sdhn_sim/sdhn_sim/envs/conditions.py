"""Deployment conditions: what the real world does between an environment and its policies.

NumPy only, no ROS, no torch. One model serves the batched in-process environments (every robot
of every env) and the ROS simulator (``sdhn_sim.lockstep`` runs it with B = 1), so a deployment
under a condition reproduces the in-process figure for the same seeds.

Conditions (``Conditions``; every default is the ideal world, and ``Conditions()`` is the
identity):

==================  ================  ===========================================================
field               allowed           effect
==================  ================  ===========================================================
latency             int >= 0          each robot's observation is ``latency`` steps old (clamped
                                      at the episode's first step)
latency_random      bool              instead: each message is 0..``latency`` steps old, drawn
                                      uniformly per robot and step
lost_actions        0 <= p < 1        each action is lost with probability p: the robot stays
slow_fraction       0 <= f <= 1       ``round(f * N)`` robots, drawn per episode, are slow ...
slow_rate           0 < r <= 1        ... and act on a step with probability r (else stay)
position_noise      0 <= p <= 1       MAIF: the robot's own position reads one cell off (up,
                                      down, left or right, drawn uniformly; clamped to the grid)
                                      with probability p per step
cell_misread        0 <= p <= 1       MAIF: each cell of the 7x7 window (not the robot's own)
                                      reads as one of the two other values (free, obstacle,
                                      robot) with probability p
failures            0 <= k < N        k robots, drawn per episode, each stop for good at a step
                                      drawn uniformly in [0, failure_horizon): they take 'stay'
                                      from then on and stay on the grid as obstacles
failure_horizon     int >= 1          see failures (default 50: about a maif-10 makespan)
randomise           bool              each episode of each env draws every severity above
                                      uniformly between the ideal world and the given value
                                      (training under randomised conditions): latency and
                                      failures an integer in 0..k, lost_actions,
                                      slow_fraction, position_noise and cell_misread in
                                      [0, p], slow_rate in [r, 1]; false: every episode at the
                                      given severities
seed                int >= 0 or None  the model's seed; None: the environment's seed
==================  ================  ===========================================================

Success under failure (MAIF): the failed robots' goals are dropped. **Survivors' success**: at some
step before the limit every robot that has not failed stands on its goal; the step is the
survivors' makespan. It is reported beside the ideal-team success (every robot on its goal), which
a failed robot off its goal makes impossible. RWARE has no goals: its figure stays deliveries per
episode.

Randomness is counter-based: every draw is a hash of (seed + env index, episode of that env,
step, robot, cell, what is drawn), so env ``b`` of a batch seeded ``s`` draws exactly what a
single environment seeded ``s + b`` draws (the environments' own convention), a reset of one env
never shifts another env's draws, and the ROS simulator, which ends an episode at the survivors'
success, reproduces the in-process outcome.

Use in process (``ConditionedEnv`` is a ``BatchedEnv``; wrap before ``FeatureEnv``)::

    cond = conditions_from_dict({"latency": 1, "lost_actions": 0.05})   # ConditionsError if bad
    env = ConditionedEnv(make_env("maif-10", num_envs=B, seed=s), cond)
    obs, state = env.reset()              # obs as the robots see them
    res = env.step(actions)               # actions as the policies chose them
    env.obs_age                           # [B, N] steps old each robot's current observation is
    for o in env.outcomes: ...            # Outcome per episode (survivors' success, counts)

Use step by step (the simulator, B = 1; ``ConditionModel`` is what ``ConditionedEnv`` runs)::

    model = ConditionModel(cond, num_envs=1, num_robots=N, seed=s, grid_size=env.size)
    model.start([0], raw_obs[None])       # a new episode in env 0 (draws slow/failed robots)
    seen = model.observe(raw_obs[None])   # [1, N, D] what the robots are sent this step
    applied = model.act(actions[None])    # [1, N] what the world executes (lost/slow/failed)
    model.failed, model.counts            # robots failed by now, cumulative counts per effect

A ``conditions:`` YAML block (launch files, the sim's ``conditions`` parameter, the trainer's
``train.conditions``) is a mapping of these field names; ``conditions_from_dict`` validates it
with a one-line error naming the field.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from .api import BatchedEnv, BoolArray, EpisodeStats, FloatArray, IntArray, StepResult, reward_name

STAY = 0  # MAIF 'stay' and RWARE 'noop' are both action 0
_WIN = 7
_COORDS = 8
_CENTRE = _COORDS + 3 * _WIN + 3
MAIF_OBS = _COORDS + _WIN * _WIN
# (dx, dy) of the MAIF actions: stay, up (y-1), down (y+1), left (x-1), right (x+1)
MAIF_DELTAS = np.array([[0, 0], [0, -1], [0, 1], [-1, 0], [1, 0]], dtype=np.int64)


class ConditionsError(ValueError):
    """A condition is invalid; the message names the field and what is allowed."""


@dataclass(frozen=True)
class Conditions:
    """The deployment conditions (see the module docstring); the defaults are the ideal world."""

    latency: int = 0
    latency_random: bool = False
    lost_actions: float = 0.0
    slow_fraction: float = 0.0
    slow_rate: float = 1.0
    position_noise: float = 0.0
    cell_misread: float = 0.0
    failures: int = 0
    failure_horizon: int = 50
    randomise: bool = False
    seed: int | None = None

    def validate(self, num_robots: int | None = None, maif: bool = True) -> Conditions:
        """Raise ConditionsError naming the first bad field; returns self."""
        for name in ("latency", "failures"):
            _int(name, getattr(self, name), 0)
        _int("failure_horizon", self.failure_horizon, 1)
        if self.seed is not None:
            _int("seed", self.seed, 0)
        for name in ("latency_random", "randomise"):
            if not isinstance(getattr(self, name), bool):
                raise ConditionsError(f"conditions.{name}: got {getattr(self, name)!r}; "
                                      "allowed: true or false")
        _prob("lost_actions", self.lost_actions, hi_open=True)
        for name in ("slow_fraction", "position_noise", "cell_misread"):
            _prob(name, getattr(self, name))
        _prob("slow_rate", self.slow_rate)
        if self.slow_rate <= 0:
            raise ConditionsError(f"conditions.slow_rate: got {self.slow_rate!r}; allowed: "
                                  "0 < r <= 1 (the fraction of steps a slow robot acts on)")
        if num_robots is not None and self.failures >= num_robots:
            raise ConditionsError(f"conditions.failures: got {self.failures}; allowed: 0 .. "
                                  f"{num_robots - 1} (one of {num_robots} robots must survive)")
        if not maif:
            for name in ("position_noise", "cell_misread"):
                if getattr(self, name):
                    raise ConditionsError(f"conditions.{name}: got {getattr(self, name)!r}; "
                                          "allowed: 0 outside MAIF (it reads MAIF observations)")
        return self

    @property
    def ideal(self) -> bool:
        """No condition is active (the model is the identity)."""
        return not self.active()

    def replace(self, **changes: Any) -> Conditions:
        return conditions_from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def active(self) -> dict[str, Any]:
        """The fields that differ from the ideal world (what a log line or /diagnostics shows)."""
        ideal = Conditions()
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "seed" and getattr(self, f.name) != getattr(ideal, f.name)}

    def label(self) -> str:
        """A short text naming the active conditions ("ideal" when none)."""
        act = self.active()
        return ", ".join(f"{k}={v}" for k, v in act.items()) if act else "ideal"


CONDITION_FIELDS = tuple(f.name for f in fields(Conditions))


def _int(name: str, v: Any, lo: int) -> None:
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
        raise ConditionsError(f"conditions.{name}: got {v!r}; allowed: an integer >= {lo}")


def _prob(name: str, v: Any, hi_open: bool = False) -> None:
    ok = (not isinstance(v, bool) and isinstance(v, int | float | np.floating)
          and np.isfinite(v) and v >= 0 and (v < 1 if hi_open else v <= 1))
    if not ok:
        raise ConditionsError(f"conditions.{name}: got {v!r}; allowed: a number in "
                              f"[0, 1{')' if hi_open else ']'}")


def conditions_from_dict(d: Mapping[str, Any] | None, num_robots: int | None = None,
                         maif: bool = True) -> Conditions:
    """A ``conditions:`` block (None or {} = ideal) -> validated ``Conditions``."""
    if d is None:
        return Conditions()
    if not isinstance(d, Mapping):
        raise ConditionsError(f"conditions: got {type(d).__name__}; allowed: a mapping of "
                              f"{', '.join(CONDITION_FIELDS)}")
    unknown = [k for k in d if k not in CONDITION_FIELDS]
    if unknown:
        raise ConditionsError(f"conditions.{unknown[0]}: unknown condition; allowed: "
                              f"{', '.join(CONDITION_FIELDS)}")
    vals = dict(d)
    for name in ("lost_actions", "slow_fraction", "slow_rate", "position_noise", "cell_misread"):
        if name in vals and isinstance(vals[name], int) and not isinstance(vals[name], bool):
            vals[name] = float(vals[name])  # YAML writes 1 for 1.0
    return Conditions(**vals).validate(num_robots, maif)


# ------------------------------------------------------------------ counter-based randomness
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)
# what is drawn (a different stream each)
_LATENCY, _LOST, _SLOW_PICK, _SLOW_STEP, _POS, _POS_DIR, _CELL, _CELL_VAL, _FAIL_PICK, \
    _FAIL_STEP, _SEVERITY = range(11)
# the severities ``randomise`` draws per episode, in the order of their sub-streams of _SEVERITY
_SEVERITIES = ("latency", "lost_actions", "slow_fraction", "slow_rate", "position_noise",
               "cell_misread", "failures")


def _mix(h: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    """splitmix64's finaliser (wrapping uint64 arithmetic)."""
    h = (h ^ (h >> np.uint64(30))) * _M1
    h = (h ^ (h >> np.uint64(27))) * _M2
    return h ^ (h >> np.uint64(31))


def _uniform(*keys: npt.ArrayLike) -> FloatArray:
    """Uniform floats in [0, 1) from integer keys (broadcast together); one per element."""
    with np.errstate(over="ignore"):
        arrs = np.broadcast_arrays(*[np.asarray(k, dtype=np.int64) for k in keys])
        h = np.zeros(arrs[0].shape, dtype=np.uint64)
        for k in arrs:
            h = _mix(h + k.astype(np.uint64) * _GOLD + _GOLD)
    return ((h >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))).astype(np.float64)


@dataclass(frozen=True)
class Outcome:
    """One finished episode of one env under conditions."""

    env_index: int
    episode: int  # the env's episode counter under the model (0, 1, ...)
    completed: bool  # the ideal-team criterion: every robot on its goal
    makespan: int | None
    survivors_completed: bool  # every robot that had not failed on its goal (MAIF)
    survivors_makespan: int | None
    failed: int  # robots that had failed when the outcome was taken
    length: int
    deliveries: int | None  # RWARE
    stats: EpisodeStats | None  # the env's own statistics; None when the survivors' success
    # came first (the env's episode goes on; the outcome is final: a failed robot never moves)


class ConditionModel:
    """The conditions for B envs x N robots: ``start`` per episode, then per step ``observe``
    (raw observations in, what the robots see out) and ``act`` (chosen actions in, executed
    actions out). ``grid_size``: the MAIF grid's size (position noise needs it), None elsewhere."""

    def __init__(self, conditions: Conditions, num_envs: int, num_robots: int, seed: int,
                 grid_size: int | None = None) -> None:
        self.cond = c = conditions.validate(num_robots, maif=grid_size is not None)
        self.num_envs = b = int(num_envs)
        self.num_robots = n = int(num_robots)
        self.seed = int(c.seed if c.seed is not None else seed)
        self.grid_size = grid_size
        self._keys = self.seed + np.arange(b, dtype=np.int64)  # env b ~ a single env seeded s+b
        self.episode = np.full(b, -1, dtype=np.int64)  # per env, counted by start()
        self.t = np.zeros(b, dtype=np.int64)  # step within the episode
        self._hist: FloatArray | None = None  # [latency + 1, B, N, D] raw observations, ring
        self.obs_age = np.zeros((b, n), dtype=np.int64)
        self.slow = np.zeros((b, n), dtype=bool)
        self.fail_step = np.full((b, n), np.iinfo(np.int64).max, dtype=np.int64)
        # this episode's severity of every env (the given ones unless ``randomise``)
        self.severity: dict[str, npt.NDArray[Any]] = {
            name: np.full(b, getattr(c, name)) for name in _SEVERITIES}
        self.counts = {"steps": 0, "stale_obs": 0, "lost_actions": 0, "slow_stays": 0,
                       "failed_stays": 0, "failed_robots": 0, "position_noise": 0,
                       "cells_misread": 0, "episodes": 0}
        self._robots = np.arange(n, dtype=np.int64)
        self._ideal = c.ideal

    @property
    def failed(self) -> BoolArray:
        """[B, N] robots that have failed by the current step."""
        return self.t[:, None] >= self.fail_step

    def state_dict(self) -> dict[str, npt.NDArray[Any]]:
        """Everything a resumed run needs to draw and delay as an uninterrupted one (the draws
        themselves are counter-based: episode and step counters suffice)."""
        out: dict[str, npt.NDArray[Any]] = {
            "episode": self.episode, "t": self.t, "obs_age": self.obs_age, "slow": self.slow,
            "fail_step": self.fail_step,
            "counts": np.array([self.counts[k] for k in sorted(self.counts)], dtype=np.int64),
            **{f"severity.{k}": v for k, v in self.severity.items()}}
        if self._hist is not None:
            out["history"] = self._hist
        return out

    def load_state_dict(self, arrays: Mapping[str, npt.NDArray[Any]]) -> None:
        """Restore ``state_dict``; ValueError naming the array that does not fit."""
        for name in ("episode", "t", "obs_age", "slow", "fail_step"):
            _copy_into(name, getattr(self, name), arrays[name])
        for k, v in self.severity.items():
            _copy_into(f"severity.{k}", v, arrays[f"severity.{k}"])
        counts = arrays["counts"]
        if counts.shape != (len(self.counts),):
            raise ValueError(f"conditions counts: shape {counts.shape}, expected "
                             f"({len(self.counts)},)")
        self.counts = {k: int(v) for k, v in zip(sorted(self.counts), counts, strict=True)}
        self._hist = arrays["history"].copy() if "history" in arrays else None

    def start(self, envs: Sequence[int] | npt.NDArray[np.int64] | None,
              raw_obs: FloatArray) -> None:
        """A new episode in ``envs`` (None: every env); ``raw_obs`` [B, N, D] holds their first
        observations (other rows are ignored)."""
        e = np.arange(self.num_envs) if envs is None else np.asarray(envs, dtype=np.int64)
        if e.size == 0:
            return
        c, n = self.cond, self.num_robots
        if self._hist is None:
            self._hist = np.zeros((c.latency + 1, *raw_obs.shape), dtype=np.float32)
        self.episode[e] += 1
        self.t[e] = 0
        self.counts["episodes"] += int(e.size)
        self._hist[:, e] = raw_obs[e]
        self.obs_age[e] = 0
        key, ep = self._keys[e][:, None], self.episode[e][:, None]
        r = self._robots[None, :]
        if c.randomise:
            self._draw_severities(e, key[:, 0], ep[:, 0])
        sev = {name: v[e] for name, v in self.severity.items()}
        self.slow[e] = False
        m = np.rint(sev["slow_fraction"] * n).astype(np.int64)  # round half to even, as round()
        if c.slow_fraction and c.slow_rate < 1:
            order = np.argsort(_uniform(key, ep, _SLOW_PICK, r), axis=1, kind="stable")
            rank = np.argsort(order, axis=1, kind="stable")  # each robot's place in the draw
            self.slow[e] = (rank < m[:, None]) & (sev["slow_rate"] < 1)[:, None]
        self.fail_step[e] = np.iinfo(np.int64).max
        if c.failures:
            pick = np.argsort(_uniform(key, ep, _FAIL_PICK, r), axis=1, kind="stable")
            pick = pick[:, :c.failures]
            at = np.floor(_uniform(key, ep, _FAIL_STEP, pick) * c.failure_horizon
                          ).astype(np.int64)
            at = np.where(np.arange(c.failures)[None, :] < sev["failures"][:, None],
                          at, np.iinfo(np.int64).max)  # this episode fails fewer robots
            rows_f = np.full((e.size, n), np.iinfo(np.int64).max, dtype=np.int64)
            np.put_along_axis(rows_f, pick, at, axis=1)
            self.fail_step[e] = rows_f

    def _draw_severities(self, e: IntArray, key: IntArray, ep: IntArray) -> None:
        """``randomise``: this episode's severities of envs ``e``, uniform between the ideal
        world and the given ones (integers for latency and failures)."""
        c = self.cond
        for i, name in enumerate(_SEVERITIES):
            u = _uniform(key, ep, _SEVERITY, i)
            given = getattr(c, name)
            if name in ("latency", "failures"):
                self.severity[name][e] = np.floor(u * (given + 1)).astype(np.int64)
            elif name == "slow_rate":
                self.severity[name][e] = given + u * (1.0 - given)
            else:
                self.severity[name][e] = u * given

    def fail(self, env: int, robot: int, since: int) -> None:
        """Fail ``robot`` of ``env`` from step ``since`` of its current episode on, outside the
        model's own draws (the ROS simulator's silent robots, sdhn_sim.lockstep): from then it
        is a failed robot like a drawn one (stays, an obstacle, its goal dropped)."""
        if since < self.fail_step[env, robot]:
            if since < self.t[env]:  # a step act() has passed: it would never count it
                self.counts["failed_robots"] += 1
            self.fail_step[env, robot] = since
        self._ideal = False

    def observe(self, raw_obs: FloatArray) -> FloatArray:
        """Record this step's raw observations [B, N, D]; return what the robots see."""
        if self._hist is None:
            raise RuntimeError("call start() before observe()")
        c = self.cond
        k = c.latency
        slot = self.t % (k + 1)
        envs = np.arange(self.num_envs)
        self._hist[slot, envs] = raw_obs
        if self._ideal:
            return raw_obs
        key, ep, t = self._keys[:, None], self.episode[:, None], self.t[:, None]
        r = self._robots[None, :]
        if k == 0:
            out = raw_obs.copy()
            self.obs_age[:] = 0
        else:
            k_e = self.severity["latency"][:, None]  # k in every env unless randomised
            d = (np.floor(_uniform(key, ep, t, _LATENCY, r) * (k_e + 1)).astype(np.int64)
                 if c.latency_random else np.broadcast_to(k_e, self.obs_age.shape))
            d = np.minimum(d, t)
            self.obs_age = d
            self.counts["stale_obs"] += int(np.count_nonzero(d))
            out = self._hist[(t - d) % (k + 1), envs[:, None], r].copy()
        if c.position_noise:
            self._position_noise(out, key, ep, t, r)
        if c.cell_misread:
            self._misread(out, key, ep, t, r)
        return out

    def _position_noise(self, out: FloatArray, key: IntArray, ep: IntArray, t: IntArray,
                        r: IntArray) -> None:
        size = self.grid_size or 0
        hit = _uniform(key, ep, t, _POS, r) < self.severity["position_noise"][:, None]
        if not hit.any():
            return
        direction = 1 + np.floor(_uniform(key, ep, t, _POS_DIR, r) * 4).astype(np.int64)
        inv = 1.0 / (size - 1)
        cell = np.rint(out[:, :, 0:2] / inv).astype(np.int64)
        moved = np.clip(cell + MAIF_DELTAS[direction], 0, size - 1)
        new = np.where(hit[:, :, None], moved, cell)
        self.counts["position_noise"] += int(np.count_nonzero(np.any(new != cell, axis=2)))
        out[:, :, 0:2] = (new * inv).astype(np.float32)

    def _misread(self, out: FloatArray, key: IntArray, ep: IntArray, t: IntArray,
                 r: IntArray) -> None:
        cells = np.arange(_WIN * _WIN, dtype=np.int64)[None, None, :]
        k3 = (key[:, :, None], ep[:, :, None], t[:, :, None])
        p = self.severity["cell_misread"][:, None, None]
        hit = _uniform(*k3, _CELL, r[:, :, None], cells) < p
        hit[:, :, _CENTRE - _COORDS] = False  # the robot's own cell
        if not hit.any():
            return
        shift = 1 + np.floor(_uniform(*k3, _CELL_VAL, r[:, :, None], cells) * 2)
        win = out[:, :, _COORDS:]
        out[:, :, _COORDS:] = np.where(hit, (win + shift) % 3, win).astype(np.float32)
        self.counts["cells_misread"] += int(np.count_nonzero(hit))

    def act(self, actions: npt.ArrayLike) -> IntArray:
        """The actions the world executes for the chosen ``actions`` [B, N]; advances the step."""
        a = np.asarray(actions, dtype=np.int64)
        c = self.cond
        self.counts["steps"] += 1
        if self._ideal:
            self.t += 1
            return a
        a = a.copy()
        key, ep, t = self._keys[:, None], self.episode[:, None], self.t[:, None]
        r = self._robots[None, :]
        failed = self.failed
        newly = self.t[:, None] == self.fail_step
        self.counts["failed_robots"] += int(np.count_nonzero(newly))
        self.counts["failed_stays"] += int(np.count_nonzero(failed & (a != STAY)))
        stay = failed.copy()
        if self.slow.any():
            rate = self.severity["slow_rate"][:, None]
            idle = self.slow & (_uniform(key, ep, t, _SLOW_STEP, r) >= rate)
            self.counts["slow_stays"] += int(np.count_nonzero(idle & ~stay & (a != STAY)))
            stay |= idle
        if c.lost_actions:
            lost = _uniform(key, ep, t, _LOST, r) < self.severity["lost_actions"][:, None]
            self.counts["lost_actions"] += int(np.count_nonzero(lost & ~stay & (a != STAY)))
            stay |= lost
        a[stay] = STAY
        self.t += 1
        return a


def _copy_into(name: str, dst: npt.NDArray[Any], src: npt.NDArray[Any]) -> None:
    if dst.shape != src.shape:
        raise ValueError(f"conditions {name}: shape {src.shape}, expected {dst.shape}")
    dst[...] = src


class ConditionedEnv:
    """A ``BatchedEnv`` under conditions: observations pass through ``ConditionModel.observe``
    and actions through ``ConditionModel.act``. ``final_obs`` stays the raw last observation,
    and the state stays the wrapped env's (the world as it is: what a centralised critic
    learns from when training under conditions, ``train.conditions``).

    ``outcomes`` (set by every ``step``) holds one ``Outcome`` per env whose episode ended at that
    step, or, under failures (MAIF), whose survivors all stood on their goals for the first time
    (taken once per episode: the env's episode then goes on to its own end, which adds no second
    outcome). An evaluation that plays one episode per env can stop at its first outcome."""

    def __init__(self, env: BatchedEnv, conditions: Conditions | Mapping[str, Any] | None,
                 seed: int | None = None) -> None:
        cond = (conditions if isinstance(conditions, Conditions)
                else conditions_from_dict(conditions))
        self.inner_env = env
        self.name = env.name
        self.num_envs = env.num_envs
        self.num_robots = env.num_robots
        self.obs_size = env.obs_size
        self.state_size = env.state_size
        self.num_actions = env.num_actions
        self.max_steps = env.max_steps
        self.reward_name = reward_name(env)
        grid = getattr(env, "size", None)
        self._maif = isinstance(grid, int) and env.obs_size == MAIF_OBS
        base_seed = seed if seed is not None else int(getattr(env, "_seed", 0))
        self.model = ConditionModel(cond, env.num_envs, env.num_robots, base_seed,
                                    grid if self._maif else None)
        self.conditions = cond
        self.outcomes: list[Outcome] = []
        self._taken = np.zeros(env.num_envs, dtype=bool)  # this episode's outcome is out

    @property
    def obs_age(self) -> IntArray:
        return self.model.obs_age

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        obs, state = self.inner_env.reset(seed=seed)
        if seed is not None and self.conditions.seed is None:
            self.model = ConditionModel(self.conditions, self.num_envs, self.num_robots, seed,
                                        self.model.grid_size)
        self.model.start(None, obs)
        self._taken[:] = False
        self.outcomes = []
        return self.model.observe(obs), state

    def step(self, actions: npt.ArrayLike) -> StepResult:
        m = self.model
        failed = m.failed.copy()  # who had failed when these actions were taken
        applied = m.act(actions)
        res = self.inner_env.step(applied)
        self.outcomes = []
        done = {ep.env_index: ep for ep in res.episodes}
        if self._maif and (self.conditions.failures or failed.any()):  # drawn or fail()ed
            self._survivors(failed, done)
        for e, ep in done.items():
            if not self._taken[e]:
                self.outcomes.append(Outcome(
                    env_index=e, episode=int(m.episode[e]), completed=ep.completed,
                    makespan=ep.makespan, survivors_completed=ep.completed,
                    survivors_makespan=ep.makespan, failed=int(failed[e].sum()),
                    length=ep.length, deliveries=ep.deliveries, stats=ep))
        if done:
            ended = np.array(sorted(done), dtype=np.int64)
            m.start(ended, res.obs)
            self._taken[ended] = False
        seen = m.observe(res.obs)
        return StepResult(obs=seen, state=res.state, reward=res.reward,
                          terminated=res.terminated, truncated=res.truncated,
                          final_obs=res.final_obs, final_state=res.final_state,
                          episodes=res.episodes)

    def _survivors(self, failed: BoolArray, done: dict[int, EpisodeStats]) -> None:
        """Outcomes of envs whose surviving robots all stand on their goals (first time)."""
        env: Any = self.inner_env
        pos, goals = env.positions, env.goals
        for e, w in getattr(env, "final_worlds", {}).items():
            pos[e], goals[e] = w.positions, w.goals
        home = np.all(pos == goals, axis=2) | failed
        t = self.model.t
        for e in np.flatnonzero(home.all(axis=1) & ~self._taken).tolist():
            on_all = bool(np.all(pos[e] == goals[e]))
            ep = done.get(e)
            self._taken[e] = True
            self.outcomes.append(Outcome(
                env_index=e, episode=int(self.model.episode[e]), completed=on_all,
                makespan=int(t[e]) if on_all else None, survivors_completed=True,
                survivors_makespan=int(t[e]), failed=int(failed[e].sum()), length=int(t[e]),
                deliveries=None, stats=ep))
