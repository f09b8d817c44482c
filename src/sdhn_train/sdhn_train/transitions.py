"""Assemble team transitions from per-robot ROS messages into ``Rollout``s (ROS-free, torch-free).

The trainer node feeds every message it receives into a :class:`TransitionAssembler`, which keys
them by (episode, step). Messages of one step arrive on 2N+1 topics in any order (DDS orders per
topic only), so a step is a *record* that fills up:

- N ``RobotObservation`` (obs, done flags), one ``TeamState`` (global state, team reward, done
  flags) and N ``RobotAction`` (action, behaviour log-prob, policy version).

Transition t of episode e needs record (e, t) with all obs, the state and all actions, plus record
(e, t+1) with all obs and the state: the latter gives the team reward of the transition (the
``team_reward`` of the state *into* step t+1), the done flags, and ``final_obs``/``final_state``
to bootstrap from. The simulator therefore publishes the terminal step of every episode (obs and
state with terminated/truncated set); nobody needs to answer it.

Transitions leave in (episode, step) order. A record that is still incomplete when ``settle_lag``
newer records have appeared (a robot's action never came: the simulator made it 'stay'; the
trainer started mid-step) is dropped and counted; so is a step of which nothing ever arrived,
once a later step of the same episode is finished. Every step the simulator made after the
trainer's first is thus a transition, a counted step drop (``DropKind.MISSED_ACTION``,
``DropKind.INCOMPLETE_STEP``, ``DropKind.STEP_NEVER_SEEN``), a terminal step, or still pending
(``flush`` settles those at the end). A step the simulator took with a robot's 'stay' (its
TeamState's ``missed_actions`` says so) is dropped at once as ``DropKind.MISSED_ACTION``, never
learned from.
The stream then has a *gap*: the transition
before it is marked truncated (the learner bootstraps from the value of the state after it, as
for a step limit) and the next segment starts with a hidden-state reset. The actors' real GRU
state is not zero there, so the first few re-computed log-probs after a gap differ from the
behaviour ones; PPO's clipped ratio absorbs that.

Policy versions: every action carries the version of the weights that chose it and its
log-prob under them. All transitions are used, whatever their version; the behaviour log-prob
goes into the PPO ratio, which is exactly the importance weight an older version needs, and the
clip bounds how far a stale sample can push. The lag (learner version minus action version) is
reported per rollout so staleness is visible.

Hidden states: a rollout that starts in the middle of an episode carries the observations and
states of the episode's earlier steps (``prefix_obs``/``prefix_state``) so the learner can compute
the actor's and critic's hidden state at the rollout's start with its current networks.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_base.drops import DropKind
from sdhn_train.rollout import Rollout

Key = tuple[int, int]  # (episode, step)
# how many recent dropped or terminal steps are remembered, so that late messages to them are
# taken quietly; far more than the steps in flight at once (settle_lag, a missed step's peers)
ACCOUNTED_MEMORY = 256



@dataclass
class _Record:
    """Everything received for one (episode, step)."""

    created: int  # value of the assembler's record counter when this record was created
    obs: npt.NDArray[np.float32]  # [N, D]
    have_obs: npt.NDArray[np.bool_]  # [N]
    actions: npt.NDArray[np.int64]  # [N]
    log_probs: npt.NDArray[np.float32]  # [N]
    versions: npt.NDArray[np.int64]  # [N]
    have_action: npt.NDArray[np.bool_]  # [N]
    state: npt.NDArray[np.float32] | None = None
    team_reward: float = 0.0
    terminated: bool = False
    truncated: bool = False
    missed: bool = False  # the simulator stepped without a robot's action: never complete

    @property
    def observed(self) -> bool:
        """All obs and the state are here (enough to be the step *after* a transition)."""
        return self.state is not None and bool(self.have_obs.all())

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated

    @property
    def complete(self) -> bool:
        return self.observed and bool(self.have_action.all())


@dataclass
class Transition:
    key: Key
    obs: npt.NDArray[np.float32]  # [N, D]
    state: npt.NDArray[np.float32]  # [S]
    actions: npt.NDArray[np.int64]  # [N]
    log_probs: npt.NDArray[np.float32]  # [N]
    versions: npt.NDArray[np.int64]  # [N]
    reward: float
    terminated: bool
    truncated: bool
    final_obs: npt.NDArray[np.float32]  # [N, D]
    final_state: npt.NDArray[np.float32]  # [S]


@dataclass
class AssembledRollout:
    """A ``Rollout`` (B = 1) plus what the trainer needs beside it."""

    rollout: Rollout
    versions: npt.NDArray[np.int64]  # [T, N] policy version of each action
    keys: list[Key]  # (episode, step) of each of the T transitions
    prefix_obs: npt.NDArray[np.float32]  # [P, N, D] same-episode steps before keys[0]
    prefix_state: npt.NDArray[np.float32]  # [P, S]

    def policy_lag(self, learner_version: int) -> float:
        """Mean of (learner version - action version) over the rollout's actions."""
        return float(np.mean(np.maximum(learner_version - self.versions, 0)))


@dataclass
class AssemblerStats:
    transitions: int = 0
    rollouts: int = 0
    gaps: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    # What the incomplete steps lacked ('state', 'obs 2', 'action 0', ...): a stream that never
    # arrives names itself here instead of hiding in the incomplete_step count.
    missing: dict[str, int] = field(default_factory=dict)
    # Incomplete steps in a row since the last transition: a trainer out of step with the team
    # (every step torn, nothing learned) shows as this growing without bound.
    incomplete_run: int = 0


class TransitionAssembler:
    """Messages in (``add_obs``/``add_action``/``add_state``), ``Rollout``s out (``pop_rollout``).

    Every ``add_*`` returns ``None`` if the message was taken, or the drop reason (one of the
    constants above). Not thread-safe: call it from one thread (the executor's).
    """

    def __init__(self, num_robots: int, obs_size: int, state_size: int, num_actions: int, *,
                 rollout_steps: int, max_steps: int, settle_lag: int = 16) -> None:
        if rollout_steps < 1:
            raise ValueError(f"rollout_steps must be >= 1, got {rollout_steps}")
        self.n, self.d, self.s = num_robots, obs_size, state_size
        self.num_actions, self.rollout_steps, self.max_steps = num_actions, rollout_steps, max_steps
        self.settle_lag = settle_lag
        self.stats = AssemblerStats()
        self._records: dict[Key, _Record] = {}
        self._counter = 0
        self._cursor: Key | None = None  # keys below this are finished (assembled or dropped)
        self._buffer: list[Transition] = []
        self._last: Transition | None = None  # the last transition emitted (maybe packed)
        # Recent steps already accounted for without a transition (terminal, or counted as a
        # drop): a message for one that arrives late is expected, not an error. The simulator's
        # topics are independent, so another robot's answer to a step can reach us after the
        # state that tells us the step had a missed action and was dropped.
        self._accounted: dict[Key, None] = {}
        self._segment_obs: list[npt.NDArray[np.float32]] = []  # this episode's steps so far
        self._segment_state: list[npt.NDArray[np.float32]] = []
        self._ready: list[AssembledRollout] = []
        self._flushing = False

    # -- input ------------------------------------------------------------------------------

    def add_obs(self, episode: int, step: int, robot_id: int, obs: npt.NDArray[np.float32], *,
                num_robots: int, terminated: bool, truncated: bool) -> DropKind | None:
        if num_robots != self.n:
            return DropKind.WRONG_TEAM_SIZE
        if not 0 <= robot_id < self.n:
            return DropKind.UNKNOWN_ROBOT
        if obs.shape != (self.d,):
            return DropKind.WRONG_OBS_LENGTH
        if not np.all(np.isfinite(obs)):
            return DropKind.NON_FINITE_OBS
        rec, reason = self._record((episode, step))
        if rec is None:
            return reason
        if rec.have_obs[robot_id]:
            return DropKind.DUPLICATE_OBS
        rec.obs[robot_id] = obs
        rec.have_obs[robot_id] = True
        self._advance()
        return None

    def add_action(self, episode: int, step: int, robot_id: int, action: int, *,
                   log_prob: float, version: int) -> DropKind | None:
        if not 0 <= robot_id < self.n:
            return DropKind.UNKNOWN_ROBOT
        if not 0 <= action < self.num_actions:
            return DropKind.ACTION_OUT_OF_RANGE
        if not (np.isfinite(log_prob) and log_prob <= 1e-6):
            return DropKind.BAD_LOG_PROB
        rec, reason = self._record((episode, step))
        if rec is None:
            return reason
        if rec.have_action[robot_id]:
            return DropKind.DUPLICATE_ACTION
        rec.actions[robot_id] = action
        rec.log_probs[robot_id] = min(log_prob, 0.0)
        rec.versions[robot_id] = version
        rec.have_action[robot_id] = True
        self._advance()
        return None

    def add_state(self, episode: int, step: int, state: npt.NDArray[np.float32], *,
                  num_robots: int, team_reward: float, terminated: bool,
                  truncated: bool, missed: int = 0) -> DropKind | None:
        """``missed``: the state's ``missed_actions``, robots the simulator made 'stay' in the
        step before; that step can never be complete, and is dropped as soon as this is known
        (``DropKind.MISSED_ACTION``) instead of after ``settle_lag`` more records."""
        if num_robots != self.n:
            return DropKind.WRONG_TEAM_SIZE
        if state.shape != (self.s,):
            return DropKind.WRONG_STATE_LENGTH
        if not (np.all(np.isfinite(state)) and np.isfinite(team_reward)):
            return DropKind.NON_FINITE_STATE
        rec, reason = self._record((episode, step))
        if rec is None:
            return reason
        if rec.state is not None:
            return DropKind.DUPLICATE_STATE
        rec.state = state
        rec.team_reward, rec.terminated, rec.truncated = team_reward, terminated, truncated
        if missed > 0 and step > 0:
            before, _ = self._record((episode, step - 1))
            if before is not None:
                before.missed = True
        self._advance()
        return None

    def restart(self) -> None:
        """Forget every pending step (a new simulator run); the next rollout starts afresh."""
        self._cut()
        self._records.clear()
        self._accounted.clear()  # the new run's keys start again at (0, 0)
        self._cursor = None
        self._segment_obs, self._segment_state = [], []
        self.stats.gaps += 1

    def flush(self) -> None:
        """The stream ended (the trainer stops): settle every pending record now, so each step
        is a transition or a counted drop, none left uncounted."""
        self._flushing = True
        try:
            self._advance()
        finally:
            self._flushing = False

    # -- output -----------------------------------------------------------------------------

    def pop_rollout(self) -> AssembledRollout | None:
        """The oldest complete rollout of ``rollout_steps`` transitions, or None."""
        return self._ready.pop(0) if self._ready else None

    @property
    def pending_records(self) -> int:
        return len(self._records)

    # -- internals --------------------------------------------------------------------------

    def _record(self, key: Key) -> tuple[_Record | None, DropKind | None]:
        episode, step = key
        if step > self.max_steps:
            return None, DropKind.FUTURE_STEP
        if self._cursor is not None and step == 0 and episode + 1 < self._cursor[0]:
            self.restart()  # the simulator restarted (its episode counter went back)
        if self._cursor is not None and key < self._cursor:
            # a late message to a step already dropped or closed: nothing to learn from, and
            # not an error (that step is already counted); else a replay of an assembled one
            return None, None if key in self._accounted else DropKind.STALE_STEP
        rec = self._records.get(key)
        if rec is None:
            self._counter += 1
            n = self.n
            rec = _Record(self._counter, np.zeros((n, self.d), np.float32), np.zeros(n, bool),
                          np.zeros(n, np.int64), np.zeros(n, np.float32), np.zeros(n, np.int64),
                          np.zeros(n, bool))
            self._records[key] = rec
        return rec, None

    def _settled(self, rec: _Record) -> bool:
        """No more messages are expected for this record: ``settle_lag`` newer ones exist."""
        return self._flushing or self._counter - rec.created >= self.settle_lag

    def _advance(self) -> None:
        """Emit every transition that is ready, in key order; drop records that never complete."""
        while self._records:
            key = min(self._records)
            rec = self._records[key]
            episode, step = key
            if rec.observed and rec.done:
                # A terminal step: it only closes the transition before it (already emitted or
                # dropped, being older). Nothing follows it in this episode.
                self._finish(key, gap=False, episode_end=True)
                continue
            nxt = self._records.get((episode, step + 1))
            # A step the simulator took with a 'stay' for a missing robot is never learned from,
            # even if that robot's late action reaches us: it is not what the world executed.
            if not rec.missed and rec.complete and nxt is not None and nxt.observed:
                self._emit(key, rec, nxt)
                continue
            if rec.missed or self._settled(rec):
                cause = DropKind.MISSED_ACTION if rec.missed else DropKind.INCOMPLETE_STEP
                self.stats.dropped[cause] = self.stats.dropped.get(cause, 0) + 1
                if not rec.missed:
                    self._count_incomplete(rec)
                self._finish(key, gap=True, episode_end=False)
                continue
            break

    def _count_incomplete(self, rec: _Record) -> None:
        """An incomplete step: what it lacked, and one more in the run without a transition."""
        m = self.stats.missing
        parts = [] if rec.state is not None else ["state"]
        parts += [f"obs {i}" for i in np.flatnonzero(~rec.have_obs)]
        parts += [f"action {i}" for i in np.flatnonzero(~rec.have_action)]
        if not parts:
            parts = ["next step"]  # complete itself, but the step after it never was
        for part in parts:
            m[part] = m.get(part, 0) + 1
        self.stats.incomplete_run += 1

    def _cut(self) -> None:
        """The stream breaks after the last emitted transition: mark it truncated (the learner
        bootstraps from the state after it and resets hidden states) unless it already ends an
        episode. If it is already packed into a rollout, the next rollout starts afresh."""
        last = self._last
        if last is not None and not (last.terminated or last.truncated):
            last.truncated = True
            if not self._buffer:
                self._segment_obs, self._segment_state = [], []

    def _count_unseen(self, key: Key) -> None:
        """Steps of this episode between the cursor and ``key`` that no message ever reached."""
        cur = self._cursor
        if cur is not None and key[0] == cur[0] and key[1] > cur[1]:
            d = self.stats.dropped
            d[DropKind.STEP_NEVER_SEEN] = d.get(DropKind.STEP_NEVER_SEEN, 0) + key[1] - cur[1]
            for step in range(max(cur[1], key[1] - ACCOUNTED_MEMORY), key[1]):
                self._remember_accounted((key[0], step))

    def _finish(self, key: Key, gap: bool, episode_end: bool) -> None:
        self._count_unseen(key)
        del self._records[key]
        self._cursor = (key[0], key[1] + 1)
        if gap:
            self.stats.gaps += 1
            self._cut()
        if gap or episode_end:
            self._remember_accounted(key)

    def _remember_accounted(self, key: Key) -> None:
        self._accounted[key] = None
        while len(self._accounted) > ACCOUNTED_MEMORY:
            del self._accounted[next(iter(self._accounted))]

    def _emit(self, key: Key, rec: _Record, nxt: _Record) -> None:
        assert rec.state is not None and nxt.state is not None
        if self._last is not None and self._last.key != (key[0], key[1] - 1):
            self._cut()  # not contiguous (records lost before they arrived)
        self._buffer.append(Transition(
            key, rec.obs, rec.state, rec.actions, rec.log_probs, rec.versions,
            float(nxt.team_reward), bool(nxt.terminated),
            bool(nxt.truncated and not nxt.terminated), nxt.obs.copy(), nxt.state.copy()))
        self._last = self._buffer[-1]
        self._count_unseen(key)
        del self._records[key]
        self._cursor = (key[0], key[1] + 1)
        self.stats.transitions += 1
        self.stats.incomplete_run = 0
        if len(self._buffer) >= self.rollout_steps:
            self._ready.append(self._pack(self._buffer))
            self._buffer = []
            self.stats.rollouts += 1

    def _pack(self, items: Sequence[Transition]) -> AssembledRollout:
        """Stack T transitions into a B = 1 rollout; track the episode prefix of the next one."""
        first = items[0]
        prefix_obs = (np.stack(self._segment_obs) if self._segment_obs
                      else np.zeros((0, self.n, self.d), np.float32))
        prefix_state = (np.stack(self._segment_state) if self._segment_state
                        else np.zeros((0, self.s), np.float32))
        if first.key[1] == 0:
            prefix_obs, prefix_state = prefix_obs[:0], prefix_state[:0]
        # The segment the next rollout continues: steps after the last episode boundary here.
        seg_obs, seg_state = list(self._segment_obs), list(self._segment_state)
        if first.key[1] == 0:
            seg_obs, seg_state = [], []
        for tr in items:
            seg_obs.append(tr.obs)
            seg_state.append(tr.state)
            if tr.terminated or tr.truncated:
                seg_obs, seg_state = [], []
        self._segment_obs, self._segment_state = seg_obs, seg_state

        def stack(name: str, dtype: type) -> Any:
            return np.stack([np.asarray(getattr(tr, name), dtype) for tr in items])[:, None]

        rollout = Rollout(
            obs=stack("obs", np.float32), state=stack("state", np.float32),
            actions=stack("actions", np.int64), log_probs=stack("log_probs", np.float32),
            rewards=stack("reward", np.float32), terminated=stack("terminated", np.bool_),
            truncated=stack("truncated", np.bool_), final_obs=stack("final_obs", np.float32),
            final_state=stack("final_state", np.float32),
            actor_h0=np.zeros((1, self.n, 0), np.float32), critic_h0=None,
        )
        versions = np.stack([tr.versions for tr in items])
        return AssembledRollout(rollout, versions, [tr.key for tr in items], prefix_obs,
                                prefix_state)
