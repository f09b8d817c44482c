"""Silent robots in the simulator core (no ROS): a robot whose observations stop at a scheduled
step (the fault schedule) goes silent, is declared failed after ``fail_after_missed`` steps,
dated back to its first silent step, and the episode's outcome is the in-process robot-failure
outcome (ConditionedEnv with that robot failed at that step) on the same instances."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_sim.envs import make_env
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions
from sdhn_sim.faults import Fault, FaultsError, faults_text, parse_faults
from sdhn_sim.lockstep import LockstepSim, SimConfig, SimConfigError

from .envs_helpers import TINY_ACTOR, Row, greedy_lockstep


def in_process_with_failure(seed: int, robot: int, at_step: int, episodes: int,
                            max_steps: int = 60) -> list[Row]:
    """Greedy play in process; ``robot`` fails at ``at_step`` of episode 0 and from step 0 of
    every later episode (a killed actor never comes back)."""
    rt = ActorRuntime.from_file(TINY_ACTOR)
    env = ConditionedEnv(make_env("maif-tiny", num_envs=1, seed=seed, max_steps=max_steps),
                         Conditions())
    obs, _ = env.reset()
    env.model.fail(0, robot, at_step)
    h = rt.initial_state(4)
    rng = np.random.default_rng(0)
    out: list[Row] = []
    while len(out) < episodes:
        a, _, h = rt.act(obs[0], h, greedy=True, rng=rng)
        res = env.step(a[None])
        out += [(o.completed, o.makespan, o.survivors_completed, o.survivors_makespan, o.failed)
                for o in env.outcomes]
        if res.episodes:
            h = rt.initial_state(4)
            env.model.fail(0, robot, 0)
        obs = res.obs
    return out[:episodes]


def lockstep_with_fault(seed: int, robot: int, at_step: int, episodes: int, *, k: int,
                        max_steps: int = 60) -> tuple[list[Row], list[dict], LockstepSim]:
    """The simulator core with the fault schedule; every robot it still sends observations to
    answers greedily, the cut one says nothing."""
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=seed, max_steps=max_steps,
                                fail_after_missed=k, faults=(Fault(0, at_step, robot),)))
    rows, events, results = greedy_lockstep(sim, episodes)
    for row, result in zip(rows, results, strict=True):
        assert result.failed_robots == row[4]
        assert result.survivors_success == row[2]
    return rows, events, sim


@pytest.mark.parametrize("robot,at_step,k", [(1, 3, 2), (2, 6, 3), (0, 1, 1)])
def test_a_cut_robot_fails_as_in_process_on_the_same_instances(robot: int, at_step: int,
                                                               k: int) -> None:
    want = in_process_with_failure(seed=7, robot=robot, at_step=at_step, episodes=3)
    got, events, sim = lockstep_with_fault(seed=7, robot=robot, at_step=at_step, episodes=3, k=k)
    assert got == want
    assert any(r[2] for r in got)  # survivors succeed somewhere: the comparison has content
    assert all(r[4] == 1 for r in got)  # failed in every episode, from step 0 after the first
    cut = [e for e in events if e["event"] == "fault"]
    failed = [e for e in events if e["event"] == "robot_failed"]
    assert [(e["robot"], e["episode"], e["step"]) for e in cut] == [(robot, 0, at_step)]
    assert failed[0]["robot"] == robot and failed[0]["since_step"] == at_step
    assert failed[0]["declared_step"] == at_step + k - 1
    assert sim.ros_failures == 1 and sim.dead[robot]
    # a failed robot is no longer waited for nor counted as missing
    assert robot not in sim.missing()


def test_an_answer_from_a_failed_robot_revives_it_at_the_next_episode() -> None:
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=3, max_steps=8, fail_after_missed=1))
    f = sim.reset()
    for i in (0, 1, 2):
        sim.submit(i, f.episode, f.step, 0, 1)
    f, _ = sim.advance()  # robot 3 silent once: failed
    assert sim.dead.tolist() == [False, False, False, True] and sim.conditions.failed[0, 3]
    assert sim.complete is False
    for i in (0, 1, 2):
        sim.submit(i, f.episode, f.step, 0, 1)
    assert sim.complete  # robot 3 is no longer waited for
    sim.submit(3, f.episode, f.step, 0, 1)  # ... but answers again
    result = None
    while result is None:
        f, result = sim.advance()
        for i in range(4):
            sim.submit(i, f.episode, f.step, 0, 1)
    assert result.failed_robots == 1
    sim.reset()
    assert not sim.dead.any() and not sim.conditions.failed[0].any()


def test_a_team_gone_silent_is_no_survivors_success() -> None:
    """Every robot silent (a network outage, not a failed robot): no survivor, no success."""
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=3, max_steps=6, fail_after_missed=1))
    sim.reset()
    result = None
    while result is None:
        _, result = sim.advance()
    assert result.failed_robots == 4 and not result.survivors_success
    assert result.length == 6


@pytest.mark.parametrize("block,field", [
    ([{"robot": 9, "at_step": 4}], "faults[0].robot"),
    ([{"robot": 1}], "faults[0].at_step"),
    ([{"robot": 1, "at_step": 0}], "faults[0].at_step"),
    ([{"robot": 1, "at_step": 3, "when": 2}], "faults[0].when"),
    ([{"robot": 1, "at_step": 3}, {"robot": 1, "at_step": 5}], "faults[1].robot"),
    ([{"robot": r, "at_step": 3} for r in range(4)], "faults:"),
    ([{"robot": 1, "at_step": 3, "episode": 2}], "faults[0].episode"),
    ("{robot: 1", "faults:"),
    ({"robot": 1}, "faults:"),
])
def test_a_bad_fault_schedule_is_named_in_one_line(block: object, field: str) -> None:
    with pytest.raises(FaultsError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_faults(block, num_robots=4, episodes=2)


def test_the_schedule_round_trips_through_its_parameter_text() -> None:
    faults = parse_faults([{"robot": 2, "at_step": 9, "episode": 1}, {"robot": 0, "at_step": 4}],
                          num_robots=4)
    assert faults == (Fault(0, 4, 0), Fault(1, 9, 2))
    assert parse_faults(faults_text(faults), num_robots=4) == faults
    with pytest.raises(SimConfigError, match="fail_after_missed"):
        SimConfig(env="maif-tiny", fail_after_missed=-1).validate()
