"""The ROS-free half of the simulator's realtime clock (sdhn_sim.lockstep, clock="realtime"):
which action a tick applies, the staleness it counts, and the actor core's skip-ahead."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_base.drops import DropKind
from sdhn_policy.actor_core import ActorCore, Decision, Drop
from sdhn_sim.lockstep import LockstepSim, SimConfig, SimConfigError

from .test_lockstep_actor_core import blob, offer


def realtime(**kw: object) -> LockstepSim:
    return LockstepSim(SimConfig(env="maif-tiny", seed=1, clock="realtime", rate_hz=10.0,
                                 **kw))  # type: ignore[arg-type]


def test_a_tick_applies_each_robots_newest_action_once_and_counts_its_staleness() -> None:
    sim = realtime(max_steps=20)
    f = sim.reset()
    n = sim.num_robots
    for i in range(n):
        assert sim.submit(i, f.episode, 0, 1, version=1) is None
    assert f.obs_age is not None and not f.obs_age.any()
    f, _ = sim.advance()  # step 0's answers applied at step 0: staleness 0
    assert sim.staleness.applied == {0: n} and f.missed == 0
    assert f.obs_age is not None and not f.obs_age.any()  # every action so far is in the world
    # Tick 1 -> 2: robot 0 answers step 1, robot 1 answers nothing new, robots 2.. late.
    assert sim.submit(0, f.episode, 1, 2, version=1) is None
    f, _ = sim.advance()
    assert f.missed == n - 1 and sim.staleness.applied == {0: n + 1}
    # the others' answers to step 1 are not in the world of step 2: one step behind
    assert f.obs_age is not None and f.obs_age.tolist() == [0] + [1] * (n - 1)
    # Tick 2 -> 3: robot 2's answer to step 1 arrives now (staleness 1); robot 3 answers step 1
    # and step 2 before the tick: step 1's answer is superseded, never applied.
    assert sim.submit(2, f.episode, 1, 3, version=1) is None
    assert sim.submit(3, f.episode, 1, 3, version=1) is None
    assert sim.submit(3, f.episode, 2, 4, version=1) is None
    f, _ = sim.advance()
    assert sim.staleness.applied == {0: n + 2, 1: 1}
    # step 3's world holds robot 0's answer to step 1, robot 1's to step 0, robot 2's to step 1
    # (applied late), robot 3's to step 2
    assert f.obs_age is not None and f.obs_age.tolist()[:4] == [1, 2, 1, 0]
    assert sim.staleness.superseded == 1 and sim.staleness.stale == 1
    assert sim.staleness.missed == (n - 1) + (n - 2)
    assert sim.ep_staleness.applied == sim.staleness.applied


def test_realtime_refuses_answers_to_the_future_to_old_steps_and_to_taken_steps() -> None:
    sim = realtime(max_steps=20)
    f = sim.reset()
    assert sim.submit(0, f.episode, 1, 1, version=0) == DropKind.FUTURE_STEP
    assert sim.submit(0, f.episode + 1, 0, 1, version=0) == DropKind.FUTURE_STEP
    assert sim.submit(0, f.episode, 0, 9, version=0) == DropKind.ACTION_OUT_OF_RANGE
    assert sim.submit(0, f.episode, 0, 1, version=0) is None
    assert sim.submit(0, f.episode, 0, 1, version=0) == DropKind.STALE_STEP  # not newer
    sim.advance()
    assert sim.submit(0, f.episode, 0, 1, version=0) == DropKind.STALE_STEP  # already applied
    assert sim.submit(1, f.episode, 0, 1, version=0) is None  # robot 1's late answer: taken


def test_answers_to_an_ended_episode_expire_and_an_episode_event_holds_its_counts() -> None:
    sim = realtime(max_steps=2, episodes=2)
    sim.reset()
    sim.advance()
    _, result = sim.advance()
    assert result is not None and result.missed_actions == 2 * sim.num_robots
    sim.reset()
    assert sim.submit(0, 0, 1, 1, version=0) is None  # the old episode's: counted, not a drop
    assert sim.staleness.expired == 1 and not sim.complete
    assert sim.ep_staleness.applied == {} and sim.staleness.missed == 2 * sim.num_robots
    event = sim.staleness.to_event()
    assert event["expired_actions"] == 1 and event["staleness"] == {}


def test_lockstep_is_unchanged_by_the_realtime_bookkeeping() -> None:
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=1, max_steps=5))
    f = sim.reset()
    assert sim.submit(0, f.episode, 0, 1, version=0) is None
    assert sim.submit(0, f.episode, 0, 1, version=0) == DropKind.DUPLICATE_ACTION
    sim.advance()
    assert sim.staleness.applied == {} and sim.staleness.missed == 0


@pytest.mark.parametrize("field,value", [("clock", "wallclock"), ("rate_hz", 0.0),
                                         ("rate_hz", float("inf")), ("rate_hz", 5000.0)])
def test_bad_realtime_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(SimConfigError, match=field):
        SimConfig(env="maif-tiny", **{field: value}).validate()  # type: ignore[arg-type]


def test_actor_core_skips_ahead_only_in_realtime() -> None:
    obs = np.zeros(57, dtype=np.float32)
    for skip, want in ((False, Drop), (True, Decision)):
        core = ActorCore(0, 4, greedy=True, seed=0, skip_ahead=skip)
        offer(core, blob(1))
        assert isinstance(core.on_obs(0, 0, 0, 4, obs), Decision)
        assert isinstance(core.on_obs(0, 3, 0, 4, obs), want)
        assert core.skipped == (2 if skip else 0)
    # skipping ahead never takes the past: step 2 after step 3
    out = core.on_obs(0, 2, 0, 4, obs)
    assert isinstance(out, Drop) and out.kind == DropKind.STALE_STEP
    # a new episode whose step 0 was skipped (depth-1 subscription): taken, the GRU reset
    core.hidden = np.ones_like(core.hidden)
    assert isinstance(core.on_obs(1, 2, 0, 4, obs), Decision)
    assert core.episode == 1 and core.last_step == 2 and core.skipped == 4
    fresh = ActorCore(0, 4, greedy=True, seed=0)
    offer(fresh, blob(1))
    fresh.on_obs(1, 0, 0, 4, obs)
    assert core.hidden is not None and np.array_equal(core.hidden, fresh.hidden)


def test_realtime_under_latency_adds_the_actions_not_yet_applied_to_the_observed_step() -> None:
    """Realtime with one step of observation latency: an observation shows the world of the step
    before, which holds each robot's actions applied before that step; ``obs_age`` counts from
    there (1 when every answer ran at its own tick, 2 for a robot whose answer is still pending)."""
    from sdhn_sim.envs.conditions import Conditions

    sim = realtime(max_steps=20, conditions=Conditions(latency=1))
    f = sim.reset()
    n = sim.num_robots
    assert f.obs_age is not None and not f.obs_age.any()
    for step in range(2):
        for i in range(n):
            assert sim.submit(i, f.episode, step, 1, version=1) is None
        f, _ = sim.advance()
        # the world of step - 1 holds the answers up to step - 2: the last one is unseen
        assert f.obs_age is not None and f.obs_age.tolist() == [1] * n, step
    for i in range(1, n):  # robot 0's answer to step 2 misses the tick
        assert sim.submit(i, f.episode, 2, 1, version=1) is None
    f, _ = sim.advance()
    assert f.obs_age is not None and f.obs_age.tolist() == [1] * n  # the world of step 2
    assert sim.submit(0, f.episode, 2, 1, version=1) is None  # applied late, at tick 3
    for i in range(1, n):
        assert sim.submit(i, f.episode, 3, 1, version=1) is None
    f, _ = sim.advance()
    # the world of step 3 lacks robot 0's answer to step 2 (applied at tick 3): two unseen
    assert f.obs_age is not None and f.obs_age.tolist() == [2] + [1] * (n - 1)
