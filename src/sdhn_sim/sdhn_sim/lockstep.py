"""The simulator's lock-step logic, without ROS: one environment, N robots, one step at a time.

The simulator node publishes a :class:`Frame` (every robot's observation + the team state), feeds
every incoming action to :meth:`LockstepSim.submit`, and calls :meth:`LockstepSim.advance` once
all N actions of the step are in or the deadline passed. A robot whose action is missing then
takes ``stay`` (action 0); the miss is counted per step and per episode. ``advance`` returns the
next frame and, when the episode ended, an :class:`EpisodeResult`; the node then publishes the
final frame (terminated/truncated set, actors do not answer it), the summary, and asks for the
next episode's first frame with :meth:`LockstepSim.reset`.

    sim = LockstepSim(SimConfig(env="maif-tiny", seed=1))
    frame = sim.reset()
    for i in range(sim.num_robots):
        sim.submit(i, frame.episode, frame.step, action=1, version=3)
    frame, result = sim.advance()

Deployment conditions (``SimConfig.conditions``, ``sdhn_sim.envs.conditions``) run through the same
``ConditionModel`` as the in-process ``ConditionedEnv`` with B = 1: frames carry the observations
as the robots see them (stale, noisy; ``Frame.obs_age``), ``advance`` executes the actions as the
world applies them (lost, slow, failed robots stay). Under failures a MAIF episode ends when every
surviving robot stands on its goal; ``last_outcome`` holds each episode's survivors' success next
to the ideal-team result, so a run reproduces the in-process figures for the same seeds (env
``b`` of an in-process batch seeded ``s`` = this simulator seeded ``s + b``).

With ``clock="realtime"`` the same object is the core of a world that steps at ``rate_hz`` and
never waits: the node calls :meth:`advance` on a timer, and ``submit`` takes an action answering
any step of the current episode up to the current one. Each robot's newest action not yet applied
is applied once, at the next tick (an older one still pending is *superseded*, counted, never
applied); a robot with none pending stays (counted as missed). Every applied action's *staleness*
is counted: the current step minus the step of the observation it answers (0 = as in lock-step;
k = what the in-process k-step observation latency gives). Why apply once rather than repeat the
last action: a MAIF or RWARE action is one discrete move, so repeating it would be a move the
policy never chose.

``Frame.obs_age`` is what each robot's observation lags behind its own actions, sent to the
actors (``RobotObservation.obs_age``) for dead reckoning: its actions for steps
``step - obs_age .. step - 1`` are not yet reflected in it. In lock-step that is the conditions'
observation latency (every action of a step is applied, or known to be lost, before the next
observation). Under the realtime clock an action still in flight, or pending for the next tick,
is not in the world yet either: the age then counts from the robot's newest applied action (the
observation of step t shows the world after the actions applied at ticks before t; with latency
k, the world as it was k steps ago).

Silent robots (``fail_after_missed`` > 0): a robot that has not answered that many steps in a row
(lock-step: deadline misses; realtime: ticks without a new action) is declared failed, by the
condition model's definition: from its first silent step on (the failure is dated back there,
as it has stood still since) it stays on the grid as an obstacle and its goal is dropped, the
episode ends at the survivors' success (also when the survivors all stood on their goals during
the silent steps before the declaration: the outcome is dated to that step, as in process), and
lock-step no longer waits for it. It stays failed in the following episodes (from their step 0)
until it answers again. ``faults`` (:mod:`sdhn_sim.faults`) cuts a robot's observations from a
scheduled step on (the launcher kills its process then); :meth:`LockstepSim.take_events` hands
the node each cut and each declared failure for its events file.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_base.drops import DropKind
from sdhn_base.errors import ConfigError
from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_sim.envs import make_single_env
from sdhn_sim.envs.api import EpisodeStats
from sdhn_sim.envs.conditions import (
    ConditionModel,
    Conditions,
    ConditionsError,
    Outcome,
    conditions_from_dict,
)
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.registry import env_names, team_size
from sdhn_sim.envs.single import SingleEnv
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.faults import Fault, FaultsError, parse_faults

STAY = 0
CLOCKS = ("lockstep", "realtime")

class SimConfigError(ConfigError):
    """A simulator setting is invalid; the message names it and the allowed values."""


def setting(default: Any, help: str, lo: float | None = None, hi: float | None = None, *,
            text_default: str | None = None) -> Any:
    """A SimConfig field (a callable ``default`` is its factory) with what the simulator node's
    ROS parameter needs: its help, its range (``lo``/``hi``, the descriptor's bounds) and, for a
    structured field that a parameter carries as YAML text, the text default. The node's
    parameter table is generated from these fields (``sdhn_sim.sim_node.PARAMETERS``), so a
    setting is defined once."""
    meta = {"help": help, "lo": lo, "hi": hi, "text_default": text_default}
    if callable(default):  # a mutable default: its factory
        return field(default_factory=default, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class SimConfig:
    """The simulator's settings, each defined once: the ROS parameters of ``sdhn_sim sim`` are
    generated from these fields (their help, range and default)."""

    env: str = setting("maif-10", f"environment registry name, one of {', '.join(env_names())}")
    seed: int = setting(0, "seed of the environment's instance stream", 0)
    episodes: int = setting(0, "episodes to run, then stop with exit 0; 0 = until stopped", 0)
    step_deadline: float = setting(1.0, "seconds to wait for all N actions of a step; a missing "
                                        "action becomes 'stay'", 0.001, 3600.0)
    instance: int = setting(-1, "MAIF instance to replay every episode; -1 = draw per episode",
                            -1)
    start_timeout: float = setting(60.0, "seconds to wait for every actor before step 0 (then "
                                         "exit 1)", 0.001, 86400.0)
    max_steps: int = setting(0, "episode step limit; 0 = the environment's default", 0)
    extra_subscribers: int = setting(0, "other nodes (trainer, recorder) whose state, obs and "
                                        "episode subscriptions to wait for before step 0", 0)
    # setting() returns a dataclasses.field with a default_factory: nothing is shared
    conditions: Conditions = setting(  # noqa: RUF009
        Conditions, "deployment conditions: a YAML/JSON mapping of sdhn_sim.envs.conditions "
        "fields, e.g. '{latency: 1}'; '' = ideal", text_default="")
    clock: str = setting("lockstep", "lockstep: step once all N actions are in (or "
                                     "step_deadline); realtime: step rate_hz times a second with "
                                     "the newest actions, never waiting")
    rate_hz: float = setting(10.0, "realtime: world steps per second", 0.001, 1000.0)
    fail_after_missed: int = setting(0, "a robot that has not answered this many steps in a row "
                                        "fails (stays as an obstacle, its goal dropped, "
                                        "sdhn_sim.envs.conditions); 0 = never", 0)
    faults: tuple[Fault, ...] = setting((), "fault schedule: YAML list of {robot, at_step[, "
                                             "episode]} whose observations stop at that step (the "
                                             "launcher kills the actor); '' = none "
                                             "(sdhn_sim.faults)", text_default="")

    def validate(self) -> None:
        """Raise SimConfigError naming the first bad field."""
        if self.env not in env_names():
            raise SimConfigError(f"env: unknown environment {self.env!r}; allowed: {env_names()}")
        if self.seed < 0:
            raise SimConfigError(f"seed: must be >= 0, got {self.seed}; allowed: integers >= 0")
        if self.episodes < 0:
            raise SimConfigError(f"episodes: must be >= 0, got {self.episodes}; allowed: "
                                 "0 (until stopped) or a positive count")
        for name in ("step_deadline", "start_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise SimConfigError(f"{name}: got {value}; allowed: finite seconds > 0")
        if self.instance < -1:
            raise SimConfigError(f"instance: got {self.instance}; allowed: -1 (draw per episode) "
                                 "or an instance id >= 0")
        if self.instance >= 0 and not self.env.startswith("maif"):
            raise SimConfigError(f"instance: fixed instances exist only for MAIF, not {self.env}; "
                                 "allowed: -1")
        if self.max_steps < 0:
            raise SimConfigError(f"max_steps: must be >= 0, got {self.max_steps}; allowed: "
                                 "0 (environment default) or a positive step limit")
        if self.extra_subscribers < 0:
            raise SimConfigError(f"extra_subscribers: got {self.extra_subscribers}; "
                                 "allowed: integers >= 0")
        if not isinstance(self.conditions, Conditions):
            raise SimConfigError(f"conditions: got {type(self.conditions).__name__}; allowed: "
                                 "a Conditions (conditions_from_dict reads a YAML block)")
        try:
            self.conditions.validate(team_size(self.env), maif=self.env.startswith("maif"))
        except ConditionsError as e:
            raise SimConfigError(str(e)) from e
        if self.clock not in CLOCKS:
            raise SimConfigError(f"clock: got {self.clock!r}; allowed: {', '.join(CLOCKS)}")
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 1000):
            raise SimConfigError(f"rate_hz: got {self.rate_hz}; allowed: steps per second in "
                                 "(0, 1000]")
        if self.fail_after_missed < 0:
            raise SimConfigError(f"fail_after_missed: got {self.fail_after_missed}; allowed: 0 "
                                 "(never) or a number of steps >= 1")
        try:
            parse_faults([f.to_dict() for f in self.faults], team_size(self.env), self.episodes)
        except FaultsError as e:
            raise SimConfigError(str(e)) from e

    @staticmethod
    def parse_conditions(block: Any) -> Conditions:
        """A ``conditions:`` block (a mapping, or its YAML/JSON text; '' = ideal) -> Conditions;
        SimConfigError naming the field if invalid."""
        if isinstance(block, str):  # the text of a ROS string parameter
            try:
                block = load_yaml(block, what="conditions") if block.strip() else None
            except YamlError as e:
                raise SimConfigError(str(e)) from e
        try:
            return conditions_from_dict(block)
        except ConditionsError as e:
            raise SimConfigError(str(e)) from e

    @property
    def realtime(self) -> bool:
        return self.clock == "realtime"


@dataclass(frozen=True)
class Frame:
    """What the simulator publishes at one lock-step (observations of every robot + team state)."""

    episode: int
    step: int
    obs: npt.NDArray[np.float32]  # [N, D]
    state: npt.NDArray[np.float32]  # [S]
    positions: npt.NDArray[np.int32]  # [N, 2] grid cells (x, y)
    instance_id: int  # the world being played (MAIF instance id; -1 without numbered instances)
    reward: float  # team reward of the transition into this step (0 at step 0)
    terminated: bool
    truncated: bool
    missed: int  # robots that took 'stay' because their action missed the deadline
    # [N] steps each robot's observation lags behind its own actions (conditions' latency; under
    # the realtime clock also its actions not yet applied); None on an episode's final frame
    obs_age: npt.NDArray[np.int64] | None = None

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def _positions(env: SingleEnv) -> npt.NDArray[np.int32]:
    return np.asarray(env.positions, dtype=np.int32).reshape(-1, 2)


class LockstepSim:
    """One environment stepped in lock-step from per-robot actions that arrive one by one."""

    def __init__(self, cfg: SimConfig) -> None:
        cfg.validate()
        self.cfg = cfg
        overrides: dict[str, Any] = {}
        if cfg.max_steps > 0:
            overrides["max_steps"] = cfg.max_steps
        if cfg.instance >= 0:
            overrides["instance_ids"] = [cfg.instance]
        try:
            self.env = make_single_env(cfg.env, seed=cfg.seed, **overrides)
        except ValueError as e:  # e.g. instance id out of range
            raise SimConfigError(f"instance: {e}") from e
        self.num_robots = self.env.num_robots
        self.obs_size = self.env.obs_size
        self.num_actions = self.env.num_actions
        inner = self.env.env
        self._maif = isinstance(inner, MaifEnv)
        self.conditions = ConditionModel(cfg.conditions, 1, self.num_robots, cfg.seed,
                                         inner.size if isinstance(inner, MaifEnv) else None)
        self.last_outcome: Outcome | None = None  # of the last finished episode
        self._ep_return = 0.0
        self._ep_collisions = 0
        self.episode = -1
        self.step = 0
        self.frame: Frame | None = None
        self._actions = np.zeros(self.num_robots, dtype=np.int64)
        self._got = np.zeros(self.num_robots, dtype=bool)
        self._ep_missed = 0
        self._ep_version = 0
        self.episodes_done = 0
        self.total_missed = 0
        self.instance_id = -1  # of the current episode, read at reset
        # realtime: the step each robot's pending action answers (-1 = none yet this episode)
        self._answers = np.full(self.num_robots, -1, dtype=np.int64)
        self.staleness = RealtimeCounts()  # since start
        # realtime: the step each robot's newest applied action answers (-1 = none this episode)
        self._applied = np.full(self.num_robots, -1, dtype=np.int64)
        # per recent step (newest last, latency + 1 kept): the first step whose action of each
        # robot the world of that step does not reflect yet (lock-step: that step itself)
        self._reflects: deque[npt.NDArray[np.int64]] = deque(
            maxlen=cfg.conditions.latency + 1)
        self.ep_staleness = RealtimeCounts()  # this episode
        # silent robots: steps in a row without an answer; declared failed (kept across episodes
        # while silent); answered again while failed (revived at the next episode)
        self._silent = np.zeros(self.num_robots, dtype=np.int64)
        self.dead = np.zeros(self.num_robots, dtype=bool)
        self._revived = np.zeros(self.num_robots, dtype=bool)
        self.cut = np.zeros(self.num_robots, dtype=bool)  # observations withheld (faults)
        self._pending_faults = list(cfg.faults)
        self._on_goal: list[npt.NDArray[np.bool_]] = []  # per step of the episode (MAIF)
        self._events: list[dict[str, Any]] = []
        self.ros_failures = 0  # robots declared failed for silence, since start

    @property
    def finished(self) -> bool:
        """True once the configured number of episodes has run (never when episodes == 0)."""
        return self.cfg.episodes > 0 and self.episodes_done >= self.cfg.episodes

    def reset(self) -> Frame:
        """Start the next episode; returns its step-0 frame."""
        obs, state = self.env.reset()
        self.episode += 1
        self.step = 0
        self._ep_missed = 0
        self._ep_version = 0
        self._ep_return = 0.0
        self._ep_collisions = 0
        self._clear()
        self._answers[:] = -1
        self._applied[:] = -1
        self._reflects.clear()
        self._reflects.append(np.zeros(self.num_robots, dtype=np.int64))
        self.ep_staleness = RealtimeCounts()
        self.instance_id = self.env.instance_id
        self.conditions.start([0], obs[None])
        self.dead &= ~self._revived
        self._revived[:] = False
        for r in np.flatnonzero(self.dead).tolist():  # still silent: failed from step 0
            self.conditions.fail(0, r, 0)
        self._on_goal = [self._goal_mask()]
        self._cut_due()
        seen = self.conditions.observe(obs[None])[0]
        self.frame = Frame(self.episode, 0, seen, state, _positions(self.env), self.instance_id,
                           0.0, False, False, 0, self._lag())
        return self.frame

    def _lag(self) -> npt.NDArray[np.int64]:
        """[N] steps each robot's current observation lags behind its own actions (Frame.obs_age):
        the observation shows the world of step ``step - latency age``, which reflects each
        robot's actions up to the step ``_reflects`` kept for it."""
        age = self.conditions.obs_age[0]
        rows = len(self._reflects) - 1 - np.minimum(age, len(self._reflects) - 1)
        reflects = np.stack(self._reflects)[rows, np.arange(self.num_robots)]
        return (self.step - reflects).astype(np.int64)

    def _clear(self) -> None:
        self._actions[:] = STAY
        self._got[:] = False

    def _goal_mask(self) -> npt.NDArray[np.bool_]:
        if not self._maif:
            return np.zeros(self.num_robots, dtype=bool)
        return np.asarray(np.all(np.asarray(self.env.positions) == np.asarray(self.env.goals),
                                 axis=1))

    def _cut_due(self) -> None:
        """Cut the observations of the robots whose scheduled fault is due at this step."""
        while self._pending_faults and (self._pending_faults[0].episode,
                                        self._pending_faults[0].at_step) <= (self.episode,
                                                                             self.step):
            f = self._pending_faults.pop(0)
            self.cut[f.robot] = True
            self._events.append({"event": "fault", "robot": f.robot, "episode": self.episode,
                                 "step": self.step, "scheduled": f.to_dict()})

    def take_events(self) -> list[dict[str, Any]]:
        """Faults cut and robots declared failed since the last call (for the events file)."""
        out, self._events = self._events, []
        return out

    def _declare_silent(self) -> None:
        """Robots silent for ``fail_after_missed`` steps in a row fail from their first silent
        step (before this step's actions are applied)."""
        k = self.cfg.fail_after_missed
        expected = ~self.conditions.failed[0]
        self._silent[self._got] = 0
        self._silent[~self._got & expected] += 1
        if k <= 0:
            return
        for r in np.flatnonzero((self._silent >= k) & expected & ~self.dead).tolist():
            since = max(0, self.step - int(self._silent[r]) + 1)
            self.conditions.fail(0, r, since)
            self.dead[r] = True
            self.ros_failures += 1
            self._events.append({"event": "robot_failed", "robot": r, "episode": self.episode,
                                 "since_step": since, "declared_step": self.step,
                                 "silent_steps": int(self._silent[r])})

    def _survivors_since(self, before: int) -> int | None:
        """The first past step (> the earliest backdated failure, < ``before``) at which every
        robot not failed by then stood on its goal: the survivors' success that a backdated
        failure reveals (None if none)."""
        fail_step = self.conditions.fail_step[0]
        first = int(fail_step.min()) + 1
        for t in range(max(first, 1), before):
            failed = fail_step <= t - 1
            if not failed.all() and bool(np.all(self._on_goal[t] | failed)):
                return t
        return None

    def submit(self, robot_id: int, episode: int, step: int, action: int,
               version: int) -> DropKind | None:
        """Take one robot's action for the current step; returns a drop kind or None if taken."""
        if not 0 <= robot_id < self.num_robots:
            return DropKind.UNKNOWN_ROBOT
        if self.cfg.realtime:
            return self._submit_realtime(robot_id, episode, step, action, version)
        if (episode, step) < (self.episode, self.step):
            return DropKind.STALE_STEP
        if (episode, step) > (self.episode, self.step):
            return DropKind.FUTURE_STEP
        if self.dead[robot_id]:
            self._revived[robot_id] = True  # it answers again: alive from the next episode
        if self._got[robot_id]:
            return DropKind.DUPLICATE_ACTION
        if not 0 <= action < self.num_actions:
            return DropKind.ACTION_OUT_OF_RANGE
        self._actions[robot_id] = action
        self._got[robot_id] = True
        self._ep_version = max(self._ep_version, int(version))
        return None

    def _submit_realtime(self, robot_id: int, episode: int, step: int, action: int,
                         version: int) -> DropKind | None:
        """Keep the newest action answering a step of this episode up to the current one."""
        if episode == self.episode - 1:
            # the answer to the last steps of the episode that just ended: too late, not bad
            self.staleness.expired += 1
            return None
        if episode < self.episode or (episode == self.episode and step <= self._answers[robot_id]):
            return DropKind.STALE_STEP  # another episode's, or not newer than one already taken
        if episode > self.episode or step > self.step:
            return DropKind.FUTURE_STEP
        if not 0 <= action < self.num_actions:
            return DropKind.ACTION_OUT_OF_RANGE
        if self.dead[robot_id]:
            self._revived[robot_id] = True
        if self._got[robot_id]:  # a newer answer before the tick: the pending one never runs
            self.staleness.superseded += 1
            self.ep_staleness.superseded += 1
        self._actions[robot_id] = action
        self._got[robot_id] = True
        self._answers[robot_id] = step
        self._ep_version = max(self._ep_version, int(version))
        return None

    @property
    def complete(self) -> bool:
        """Every robot's action for the current step is in (realtime: every robot has one
        pending, whichever step it answers); robots declared failed are not waited for."""
        return bool((self._got | self.dead).all())

    def missing(self) -> list[int]:
        return [int(i) for i in np.flatnonzero(~self._got & ~self.dead)]

    def advance(self) -> tuple[Frame, EpisodeResult | None]:
        """Step the world with the actions in (missing -> stay); returns the next frame and, when
        the episode ended, its result (call :meth:`reset` for the next one)."""
        backdated = self.ros_failures
        self._declare_silent()
        backdated = self.ros_failures > backdated
        missed = int((~self._got & ~self.dead).sum())  # a failed robot is no longer expected
        self._ep_missed += missed
        self.total_missed += missed
        if self.cfg.realtime:
            stale = self.step - self._answers[self._got]
            for counts in (self.staleness, self.ep_staleness):
                counts.add(stale, missed)
            self._applied[self._got] = self._answers[self._got]
        failed = self.conditions.failed[0].copy()  # who had failed when these actions were taken
        applied = self.conditions.act(self._actions[None])[0]
        res = self.env.step(applied)
        self.step += 1
        self._reflects.append(self._applied + 1 if self.cfg.realtime
                              else np.full(self.num_robots, self.step, dtype=np.int64))
        self._clear()
        self._ep_return += res.reward
        if "robot_collisions" in res.info:
            self._ep_collisions += int(np.sum(res.info["robot_collisions"]))
        stats: EpisodeStats | None = res.info.get("episode")
        on_goal = self._goal_mask()
        self._on_goal.append(on_goal)
        survivors_at = (self._survivors_since(self.step) if backdated and self._maif else None)
        survivors = self._maif and bool(failed.any()) and not failed.all() and (
            survivors_at is not None or bool(np.all(on_goal | failed)))
        done = res.terminated or res.truncated or survivors
        obs, age = res.obs, None
        if not done:
            obs = self.conditions.observe(res.obs[None])[0]
            age = self._lag()
        self.frame = Frame(self.episode, self.step, obs, res.state, _positions(self.env),
                           self.instance_id, res.reward, res.terminated or survivors,
                           res.truncated and not survivors, missed, age)
        result = None
        if done:
            self.episodes_done += 1
            if stats is None:  # the survivors' success ended the episode before the env did
                stats = EpisodeStats(env_index=0, episode_return=self._ep_return,
                                     length=self.step, makespan=None, completed=False,
                                     collisions=self._ep_collisions, formation_error=0.0)
            self.last_outcome = Outcome(
                env_index=0, episode=int(self.conditions.episode[0]), completed=stats.completed,
                makespan=stats.makespan, survivors_completed=stats.completed or survivors,
                survivors_makespan=stats.makespan if stats.completed
                else (survivors_at or self.step) if survivors else None,
                failed=int(failed.sum()), length=self.step, deliveries=stats.deliveries,
                stats=stats)
            result = dataclasses.replace(EpisodeResult.from_stats(
                stats, env_name=self.cfg.env, episode=self.episode,
                missed_actions=self._ep_missed, policy_version=self._ep_version,
                instance_id=self.instance_id),
                failed_robots=self.last_outcome.failed,
                survivors_completed=self.last_outcome.survivors_completed,
                survivors_makespan=self.last_outcome.survivors_makespan)
        else:
            self._cut_due()
        return self.frame, result


@dataclass
class RealtimeCounts:
    """What the realtime clock did to the actions: staleness of every applied action (steps
    between the observation it answers and the step it is applied at), ticks without a pending
    action (the robot stayed), actions superseded by a newer one before their tick."""

    applied: dict[int, int] = field(default_factory=dict)  # staleness -> applied actions
    missed: int = 0
    superseded: int = 0
    expired: int = 0  # answers to an episode that ended before they arrived (not applied)

    def add(self, staleness: npt.NDArray[np.int64], missed: int) -> None:
        for k, c in zip(*np.unique(staleness, return_counts=True), strict=True):
            self.applied[int(k)] = self.applied.get(int(k), 0) + int(c)
        self.missed += missed

    @property
    def applied_total(self) -> int:
        return sum(self.applied.values())

    @property
    def stale(self) -> int:
        """Applied actions that answer an older step than the one they were applied at."""
        return sum(c for k, c in self.applied.items() if k > 0)

    @property
    def mean(self) -> float:
        """Mean staleness of the applied actions (NaN before the first)."""
        n = self.applied_total
        return sum(k * c for k, c in self.applied.items()) / n if n else math.nan

    def to_event(self) -> dict[str, object]:
        """As the simulator's events hold it (JSON keys are strings)."""
        return {"staleness": {str(k): c for k, c in sorted(self.applied.items())},
                "stale_actions": self.stale, "superseded_actions": self.superseded,
                "expired_actions": self.expired}
