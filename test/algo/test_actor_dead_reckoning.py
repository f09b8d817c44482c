"""The actor core's dead-reckoning bookkeeping (sdhn_policy.actor_core): which of the robot's sent
actions an observation ``obs_age`` steps behind them has not seen, across skipped steps, stray and
repeated messages, a restart mid-episode and a new episode; a missing or impossible age is a
counted drop that leaves the core as it was."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sdhn_base.drops import DropKind
from sdhn_policy.actor_core import ActorCore, Decision, Drop
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.dead_reckoning import DeadReckoner
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_instances import load_instances

TINY = "models/maif-tiny-sdhn/actor.safetensors"
GRID = 12  # maif-tiny


@pytest.fixture(scope="module")
def rt() -> ActorRuntime:
    return ActorRuntime.from_file(TINY)


def core(rt: ActorRuntime, **kw: object) -> ActorCore:
    return ActorCore(0, 4, greedy=True, seed=0, runtime=rt, reckoner=DeadReckoner(1, GRID),
                     **kw)  # type: ignore[arg-type]


def stale_observations(latency: int, steps: int, seed: int = 3) -> list[np.ndarray]:
    """Robot 0's observations as a ``latency``-step condition shows them, the robots acting
    greedily on the true ones (any fixed play will do: only the bookkeeping is under test)."""
    rt = ActorRuntime.from_file(TINY)
    env = ConditionedEnv(MaifEnv(load_instances("maif-tiny"), num_envs=1, seed=seed,
                                 max_steps=200), Conditions(latency=latency))
    obs, _ = env.reset()
    h = rt.initial_state(4)
    out = []
    for _ in range(steps):
        out.append(obs[0, 0].copy())
        a, _, h = rt.act(obs[0], h, greedy=True, rng=np.random.default_rng(0))
        obs = env.step(a[None]).obs
    return out


def test_in_order_steps_reckon_like_the_in_process_rule(rt: ActorRuntime) -> None:
    """Every step answered, each observation one step behind: the core moves it by exactly the
    last action, as sdhn_policy.dead_reckoning does in process (a plain core fed the observation
    that rule gives decides the same, step after step)."""
    c, plain, mirror = core(rt), ActorCore(0, 4, greedy=True, seed=0, runtime=rt), \
        DeadReckoner(1, GRID)
    moved = 0
    for t, o in enumerate(stale_observations(1, 30)):
        age = min(t, 1)
        fed = mirror.correct(o[None], [age])[0]
        moved += int(not np.array_equal(fed, o))
        got, want = c.on_obs(0, t, 0, 4, o, obs_age=age), plain.on_obs(0, t, 0, 4, fed)
        assert isinstance(got, Decision) and got == want, t
        mirror.record([got.action])
    assert moved > 5 and c.reckoned >= moved  # the rule did move observations


def test_unseen_actions_follow_the_steps_answered_not_the_messages(rt: ActorRuntime) -> None:
    """Realtime (skip_ahead): steps the robot never answered sent nothing, so they move
    nothing; an age reaching before the episode's first answer counts only what was sent."""
    c = core(rt, skip_ahead=True)
    o = stale_observations(0, 1)[0]
    for step in (0, 1, 3, 6):  # steps 2, 4, 5 skipped
        assert isinstance(c.on_obs(0, step, 0, 4, o, obs_age=0), Decision)
    assert c.skipped == 3
    assert c.unseen_actions(7, 1) == 1  # step 6's action
    assert c.unseen_actions(7, 2) == 1  # step 5 sent nothing
    assert c.unseen_actions(7, 4) == 2  # steps 3 and 6
    assert c.unseen_actions(7, 7) == 4  # all four
    assert c.unseen_actions(6, 3) == 1  # an observation of step 6 has not seen step 3's
    assert c.unseen_actions(7, 0) == 0


def test_stray_and_repeated_observations_leave_the_bookkeeping_alone(rt: ActorRuntime) -> None:
    c = core(rt)
    obs = stale_observations(2, 6)
    for t in range(4):
        assert isinstance(c.on_obs(0, t, 0, 4, obs[t], obs_age=min(t, 2)), Decision)
    before, reckoned = list(c._sent_steps), c.reckoned
    for step, kind in ((2, DropKind.STALE_STEP), (3, DropKind.STALE_STEP),
                       (6, DropKind.FUTURE_STEP)):
        out = c.on_obs(0, step, 0, 4, obs[min(step, 5)], obs_age=2)
        assert isinstance(out, Drop) and out.kind == kind
    assert list(c._sent_steps) == before and c.reckoned == reckoned
    assert c.unseen_actions(4, 2) == 2  # steps 2 and 3, as before the stray messages
    assert isinstance(c.on_obs(0, 4, 0, 4, obs[4], obs_age=2), Decision)
    assert c.reckoned == reckoned + 1


def test_a_restarted_actor_and_a_new_episode_start_with_nothing_unseen(rt: ActorRuntime) -> None:
    obs = stale_observations(2, 12)
    fresh, plain = core(rt), ActorCore(0, 4, greedy=True, seed=0, runtime=rt)
    # restarted mid-episode: its predecessor's actions are unknown to it, nothing is moved
    assert fresh.on_obs(0, 9, 0, 4, obs[9], obs_age=2) == plain.on_obs(0, 9, 0, 4, obs[9])
    assert fresh.reckoned == 0
    assert fresh.unseen_actions(10, 2) == 1  # its own answer to step 9 from now on
    # a new episode: the last episode's actions are forgotten
    assert isinstance(fresh.on_obs(0, 10, 0, 4, obs[10], obs_age=2), Decision)
    assert isinstance(fresh.on_obs(1, 0, 0, 4, obs[0], obs_age=0), Decision)
    assert list(fresh._sent_steps) == [0] and fresh.unseen_actions(1, 1) == 1
    # realtime: a later episode may start past its step 0 (skipped); the same holds
    skipping = core(rt, skip_ahead=True)
    for step in (3, 4):
        assert isinstance(skipping.on_obs(0, step, 0, 4, obs[step], obs_age=0), Decision)
    assert isinstance(skipping.on_obs(1, 2, 0, 4, obs[2], obs_age=2), Decision)
    assert list(skipping._sent_steps) == [2] and skipping.reckoned == 0
    skipping.forget_position()  # a deactivated actor, as after a restart
    assert not skipping._sent_steps


@pytest.mark.parametrize("age,step", [(None, 3), (4, 3), (-1, 3), (1, 0)],
                         ids=["missing", "before_step_0", "negative", "at_step_0"])
def test_a_missing_or_impossible_age_is_a_counted_drop_that_changes_nothing(
        rt: ActorRuntime, age: int | None, step: int) -> None:
    c = core(rt)
    o = stale_observations(0, 1)[0]
    for t in range(step):
        assert isinstance(c.on_obs(0, t, 0, 4, o, obs_age=0), Decision)
    hidden, sent = c.hidden.copy(), list(c._sent_steps)  # type: ignore[union-attr]
    out = c.on_obs(0, step, 0, 4, o, obs_age=age)
    assert isinstance(out, Drop) and out.kind == DropKind.BAD_OBS_AGE
    assert np.array_equal(c.hidden, hidden) and list(c._sent_steps) == sent
    assert c.last_step == (step - 1 if step else None)
    assert isinstance(c.on_obs(0, step, 0, 4, o, obs_age=0), Decision)  # the step still taken


def test_without_dead_reckoning_the_age_is_not_read(rt: ActorRuntime) -> None:
    """An actor without dead reckoning takes messages of the older definition as it did."""
    c = ActorCore(0, 4, greedy=True, seed=0, runtime=rt)
    o = stale_observations(0, 1)[0]
    assert isinstance(c.on_obs(0, 0, 0, 4, o, obs_age=None), Decision)
    assert isinstance(c.on_obs(0, 1, 0, 4, o, obs_age=7), Decision)


def play_side_by_side(rt: ActorRuntime, sim: Any, cores: list[ActorCore], *, frame: Any,
                      env: ConditionedEnv, obs: np.ndarray, batch: Any,
                      robot_id: np.ndarray | None = None, steps: int = 150) -> None:
    """Up to ``steps`` steps of the lock-step simulator (its frames with ``obs_age``, one actor
    core per robot) beside the in-process env (one batched reckoner ``batch``), both from their
    first frame: the same ages and the same greedy actions step for step."""
    n = len(cores)
    h = rt.initial_state(n)
    for t in range(steps):
        assert np.array_equal(frame.obs_age, env.obs_age[0]), t
        want, _, h = rt.act(batch.correct(obs[0], env.obs_age[0]), h, greedy=True,
                            rng=np.random.default_rng(0), robot_id=robot_id)
        batch.record(want)
        got = []
        for i, c in enumerate(cores):
            out = c.on_obs(frame.episode, frame.step, i, n, frame.obs[i],
                           obs_age=int(frame.obs_age[i]))
            assert isinstance(out, Decision)
            got.append(out.action)
            sim.submit(i, frame.episode, frame.step, out.action, 1)
        assert got == want.tolist(), t
        frame, result = sim.advance()
        obs = env.step(want[None]).obs
        if result is not None:
            break


def test_lockstep_actors_with_dead_reckoning_act_as_the_in_process_batch() -> None:
    """The deployment's path (the lock-step simulator's frames with ``obs_age``, one actor core
    per robot) and the in-process one (``ConditionedEnv`` and one batched reckoner, as
    condition_eval runs it) choose the same actions step for step: greedy maif-20 under one
    step of latency, 150 steps (the two once parted at step 111 on one bit of a coordinate)."""
    from sdhn_sim.envs import make_env
    from sdhn_sim.lockstep import LockstepSim, SimConfig

    rt = ActorRuntime.from_file("models/maif-20-sdhn/actor.safetensors")
    sim = LockstepSim(SimConfig(env="maif-20", seed=11, max_steps=500,
                                conditions=Conditions(latency=1)))
    n = sim.num_robots
    cores = [ActorCore(i, n, True, 11, rt, reckoner=DeadReckoner(1, 64)) for i in range(n)]
    frame = sim.reset()
    env = ConditionedEnv(make_env("maif-20", num_envs=1, seed=0, max_steps=500,
                                  instance_order="round_robin", instance_ids=[sim.instance_id]),
                         Conditions(latency=1))
    obs, _ = env.reset()
    play_side_by_side(rt, sim, cores, frame=frame, env=env, obs=obs, batch=DeadReckoner(n, 64))
    assert sum(c.reckoned for c in cores) > 100  # the rule did move observations


def test_lockstep_rware_actors_with_dead_reckoning_act_as_the_in_process_batch() -> None:
    """The same on RWARE: each actor core gets rware-3's rule (``reckoner_for``), the batch
    ``RwareDeadReckoner``; the shipped rware-3 policy (robot ids, GRU) under one step of
    latency chooses the same actions in both, step for step, and the rule moves observations."""
    from sdhn_policy.dead_reckoning import RwareDeadReckoner, reckoner_for
    from sdhn_sim.envs import make_env
    from sdhn_sim.envs.rware_batched import RwareBatchedEnv
    from sdhn_sim.lockstep import LockstepSim, SimConfig

    rt = ActorRuntime.from_file("models/rware-3-mappo/actor.safetensors")
    sim = LockstepSim(SimConfig(env="rware-3", seed=11, max_steps=500,
                                conditions=Conditions(latency=1)))
    n = sim.num_robots
    cores = [ActorCore(i, n, True, 11, rt, reckoner=reckoner_for("rware-3")) for i in range(n)]
    frame = sim.reset()
    inner = make_env("rware-3", num_envs=1, seed=11, max_steps=500)
    assert isinstance(inner, RwareBatchedEnv)
    env = ConditionedEnv(inner, Conditions(latency=1))
    obs, _ = env.reset()
    assert np.array_equal(frame.obs, obs[0])  # the same warehouse
    play_side_by_side(rt, sim, cores, frame=frame, env=env, obs=obs,
                      batch=RwareDeadReckoner(n, inner.layout), robot_id=np.arange(n))
    assert sum(c.reckoned for c in cores) > 100


def test_a_rule_for_another_observation_is_refused(rt: ActorRuntime) -> None:
    from sdhn_policy.dead_reckoning import reckoner_for
    from sdhn_policy.weights import IncompatibleWeightsError

    with pytest.raises(IncompatibleWeightsError, match="dead reckoning for this env reads"):
        ActorCore(0, 4, greedy=True, seed=0, runtime=rt, reckoner=reckoner_for("rware-3"))
    with pytest.raises(ValueError, match="allowed: one of maif"):
        reckoner_for("nowhere")
