"""sdhn_policy.stall_breaker on hand-made MAIF observations with known answers, ActorCore with it
(one robot, as an actor process runs it) and the same rule in the batched evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sdhn_policy.actor_core import ActorCore, Decision
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.stall_breaker import StallBreaker, StallRule
from sdhn_policy.weights import IncompatibleWeightsError
from sdhn_sim.envs.maif import COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "models" / "maif-tiny-sdhn" / "actor.safetensors"
RWARE = ROOT / "models" / "rware-3-mappo" / "actor.safetensors"
SCALE = 1.0 / 11  # maif-tiny's grid is 12 x 12


def obs(x: int, y: int, gx: int, gy: int, *, neighbour: bool = False, centroid: float = 0.5
        ) -> np.ndarray:
    o = np.zeros(OBS_SIZE, dtype=np.float32)
    o[0:8] = [x * SCALE, y * SCALE, centroid, centroid, gx * SCALE, gy * SCALE, 0.5, 0.5]
    if neighbour:  # a robot in the cell to the right
        o[COORD_FEATURES + RADIUS * WINDOW + RADIUS + 1] = 2.0
    return o


def run(rule: StallRule, seq: list[np.ndarray]) -> list[bool]:
    b = StallBreaker(rule, 1)
    return [bool(b.update(o[None])[0]) for o in seq]


def test_a_robot_on_its_goal_yields_only_after_a_standstill_next_to_a_robot() -> None:
    rule = StallRule(calm_steps=3, progress_steps=5, sample_steps=2)
    still = obs(4, 4, 4, 4, neighbour=True)
    # unchanged observations: calm 0, 1, 2, 3 -> samples at the 4th step, for 2 steps, then
    # (still calm) again 2 steps later
    assert run(rule, [still] * 8) == [False, False, False, True, True, True, True, True]
    alone = obs(4, 4, 4, 4)
    assert run(rule, [alone] * 8) == [False] * 8  # on its goal with nobody next to it: waits
    # the team moving (its centroid in the observation changes) is not a standstill
    moving = [obs(4, 4, 4, 4, neighbour=True, centroid=0.1 * k) for k in range(8)]
    assert run(rule, moving) == [False] * 8


def test_a_robot_off_its_goal_samples_when_it_stops_getting_closer() -> None:
    rule = StallRule(calm_steps=50, progress_steps=3, sample_steps=1)
    closer = [obs(k, 0, 6, 0, centroid=0.1 * k) for k in range(4)]  # distance 6, 5, 4, 3
    pacing = [obs(3 + (k % 2), 0, 6, 0, centroid=0.2 + 0.1 * k) for k in range(6)]
    # best distance 2 at pacing[1]; pacing[2..] never beats it: no progress 1, 2, 3 -> sample
    got = run(rule, closer + pacing)
    assert got[:6] == [False] * 6 and got[8] is True, got
    assert run(rule, [obs(k, 0, 9, 0, centroid=0.1 * k) for k in range(9)]) == [False] * 9


def test_reset_forgets_the_episode() -> None:
    rule = StallRule(calm_steps=2, progress_steps=99, sample_steps=1)
    b = StallBreaker(rule, 2)
    still = np.stack([obs(4, 4, 4, 4, neighbour=True)] * 2)
    assert [bool(b.update(still)[0]) for _ in range(3)] == [False, False, True]
    b.reset([0])
    assert b.update(still).tolist() == [False, True]  # row 0 starts over, row 1 does not


def test_rule_parse_and_check() -> None:
    assert StallRule.parse("2,10,3") == StallRule()
    assert StallRule.parse("2, 4, 1, 0.5") == StallRule(2, 4, 1, 0.5)
    assert StallRule.parse(StallRule(2, 4, 1, 0.5).text()) == StallRule(2, 4, 1, 0.5)
    for bad in ["3,5", "3,5,x", "0,5,3", "3,5,3,0", "3,5,3,nan"]:
        with pytest.raises(ValueError, match="stall rule"):
            StallRule.parse(bad)
    with pytest.raises(ValueError, match="MAIF observations"):
        StallBreaker(StallRule(), 1).update(np.zeros((1, 71)))


class Recorder(ActorRuntime):
    """The real runtime, recording whether each step was greedy."""

    calls: list[bool]

    def act(self, obs, hidden, greedy, rng, robot_id=None, *, temperature=1.0):  # type: ignore[no-untyped-def]
        self.calls.append(bool(greedy))
        return super().act(obs, hidden, greedy, rng, robot_id, temperature=temperature)


def test_actor_core_breaks_its_own_stall_and_starts_over_each_episode() -> None:
    rt = Recorder.from_file(TINY)
    rt.calls = []
    core = ActorCore(0, 4, greedy=True, seed=0, runtime=rt,
                     stall_rule=StallRule(calm_steps=2, progress_steps=99, sample_steps=1))
    still = obs(4, 4, 4, 4, neighbour=True)
    for step in range(4):
        assert isinstance(core.on_obs(0, step, 0, 4, still), Decision)
    assert rt.calls == [True, True, False, False]
    assert isinstance(core.on_obs(1, 0, 0, 4, still), Decision)  # a new episode: calm again
    assert rt.calls[-1] is True


def test_actor_core_refuses_stall_breaking_where_it_cannot_apply() -> None:
    with pytest.raises(ValueError, match="greedy"):
        ActorCore(0, 4, greedy=False, seed=0, stall_rule=StallRule())
    with pytest.raises(IncompatibleWeightsError, match="MAIF observations"):
        ActorCore(0, 3, greedy=True, seed=0, runtime=ActorRuntime.from_file(RWARE),
                  stall_rule=StallRule())


def test_batched_resample_draws_only_for_the_rows_that_sample() -> None:
    """The evaluations' batched step: rows flagged this step take the policy's sampled action at
    the rule's temperature, the others keep the argmax; no row flagged, no draw at all."""
    rt = Recorder.from_file(TINY)
    rt.calls = []
    rule = StallRule(calm_steps=2, progress_steps=99, sample_steps=1, temperature=50.0)
    breaker = StallBreaker(rule, 2)
    # row 0 stands on its goal beside a robot; row 1 walks towards its goal, so never stalls
    h = rt.initial_state(2)
    greedy = np.array([4, 4], dtype=np.int64)  # an action neither row would sample every time
    rng = np.random.default_rng(0)
    for step in range(2):
        flat = np.stack([obs(4, 4, 4, 4, neighbour=True), obs(step, 0, 9, 0)])
        assert breaker.resample(rt, flat, h, greedy, rng=rng).tolist() == [4, 4]
    untouched = np.random.default_rng(0).bit_generator.state
    assert rt.calls == [] and rng.bit_generator.state == untouched
    seen = set()
    for step in range(2, 40):
        flat = np.stack([obs(4, 4, 4, 4, neighbour=True), obs(step % 9, 0, 9, 0)])
        act = breaker.resample(rt, flat, h, greedy, rng=rng)
        assert act[1] == 4, "a row that does not sample keeps the greedy action"
        seen.add(int(act[0]))
    assert rt.calls and not any(rt.calls), "the draws are sampled (greedy=False)"
    assert len(seen) > 1, f"row 0 kept one action {seen} at temperature 50"


def test_the_rule_a_deployment_mode_names() -> None:
    assert StallRule.of_mode({"greedy": True}) is None
    assert StallRule.of_mode({"break_stalls": False, "stall_rule": "1,2,3"}) is None
    assert StallRule.of_mode({"break_stalls": True}) == StallRule()
    assert StallRule.of_mode({"break_stalls": True, "stall_rule": ""}) == StallRule()
    assert StallRule.of_mode({"break_stalls": True, "stall_rule": "1,2,3"}) == StallRule(1, 2, 3)
    with pytest.raises(ValueError, match="stall rule"):
        StallRule.of_mode({"break_stalls": True, "stall_rule": "1,2"})
