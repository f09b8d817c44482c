"""Dead reckoning (sdhn_policy.dead_reckoning): a stale MAIF observation moved forward by the
robot's own sent actions reproduces the true current observation where nothing else moved."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_policy.actor_core import ActorCore, Decision
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.dead_reckoning import DeadReckoner
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_instances import MaifConfig, MaifInstances, load_instances

SOLO = "maif-solo"


def solo_env(seed: int = 0) -> MaifEnv:
    return MaifEnv(load_instances(SOLO), num_envs=1, seed=seed)


def test_no_age_or_no_history_changes_nothing() -> None:
    dr = DeadReckoner(2, grid_size=12)
    o = np.random.default_rng(0).random((2, 57)).astype(np.float32)
    assert np.array_equal(dr.correct(o, [0, 0]), o)
    assert np.array_equal(dr.correct(o, [3, 3]), o)  # nothing sent yet this episode


@pytest.mark.parametrize("delay", [1, 2, 3])
def test_a_lone_robot_moved_forward_sees_what_it_sees_now(delay: int) -> None:
    # one robot alone: only its own moves change its observation, so the prediction is exact
    # wherever the moves it sent were not refused
    env = solo_env()
    obs, _ = env.reset(seed=1)
    hist = [obs[0, 0]]
    dr = DeadReckoner(1, grid_size=env.size)
    rng = np.random.default_rng(3)
    exact = 0
    for _ in range(40):
        a = int(rng.integers(1, 5))
        dr.record([a])
        before = env.positions[0, 0].copy()
        res = env.step(np.array([[a]]))
        if res.episodes:
            break
        hist.append(res.obs[0, 0])
        pred = dr.correct(hist[-1 - delay][None] if len(hist) > delay else hist[0][None],
                          [min(delay, len(hist) - 1)])[0]
        moved_ok = not np.array_equal(before, env.positions[0, 0])
        if moved_ok:
            # bit for bit: the cell encoded as the environment encodes it
            exact += int(np.array_equal(pred[0:2], hist[-1][0:2]))
        # the window never claims a robot or obstacle at the robot's own cell
        assert pred[8 + 24] == 0.0
    assert exact > 10


def test_a_row_is_corrected_as_it_would_be_alone() -> None:
    """A batch (in process) and a lone robot (the actor) decide on the same inputs: a row
    nothing moves comes back bit for bit, whatever the other rows do (a rewritten coordinate
    one bit off flips a policy's argmax some steps later)."""
    rng = np.random.default_rng(5)
    o = rng.random((3, 57)).astype(np.float32)
    o[:, 8:] = rng.integers(0, 2, (3, 49)) * 1.0
    o[:, 8 + 24] = 0.0
    o[:, 0:2] = np.array([[7, 9], [3, 4], [30, 1]], dtype=np.int64) * np.float32(1 / 31)
    o[2, 0:2] += np.float32(1e-7)  # a coordinate a bit off the grid's encoding stays as it was
    batch, rows = DeadReckoner(3, grid_size=32), [DeadReckoner(1, grid_size=32) for _ in range(3)]
    for a in ([4, 0, 0], [1, 0, 0]):
        batch.record(a)
        for r, ai in zip(rows, a, strict=True):
            r.record([ai])
    got = batch.correct(o, [2, 2, 2])
    for i, r in enumerate(rows):
        assert np.array_equal(got[i], r.correct(o[i:i + 1], [2])[0])
    assert np.array_equal(got[1:], o[1:])  # 'stay' moved nothing: untouched
    if not np.array_equal(got[0], o[0]):  # moved: the environment's encoding of the new cell
        cell = np.rint(got[0, 0:2] * 31).astype(np.int64)
        assert np.array_equal(got[0, 0:2], (cell * np.float32(1 / 31)).astype(np.float32))


def test_moves_into_a_seen_obstacle_are_predicted_refused() -> None:
    dr = DeadReckoner(1, grid_size=12)
    o = np.zeros((1, 57), dtype=np.float32)
    o[0, 0:2] = 5 / 11
    o[0, 8 + 3 * 7 + 4] = 1.0  # obstacle right of the robot
    dr.record([4])  # right: refused
    dr.record([1])  # up: taken
    got = dr.correct(o, [2])[0]
    assert np.allclose(got[0:2], [5 / 11, 4 / 11])
    # the window moved one row up: the obstacle is now down-right of the robot
    assert got[8 + 4 * 7 + 4] == 1.0 and got[8 + 3 * 7 + 4] == 0.0
    # the new top row came into view: free on the grid
    assert np.all(got[8:8 + 7] == 0.0)


def test_the_grid_edge_comes_into_view_as_obstacle_and_stops_moves() -> None:
    dr = DeadReckoner(1, grid_size=12)
    o = np.zeros((1, 57), dtype=np.float32)
    o[0, 8:] = np.where(np.arange(49) // 7 < 3, 1.0, 0.0)  # y = 0: the rows above are outside
    o[0, 8 + 24] = 0.0
    o[0, 0:2] = [5 / 11, 1 / 11]
    o[0, 8:8 + 14] = [1.0] * 14
    o[0, 8 + 14:8 + 21] = 0.0  # robot at y = 1: two rows of wall above, then row y = 0
    dr.record([1])
    dr.record([1])  # the second 'up' would leave the grid
    got = dr.correct(o, [2])[0]
    assert np.allclose(got[0:2], [5 / 11, 0.0])
    assert np.all(got[8:8 + 21] == 1.0)  # three rows above y = 0: outside


def test_dead_reckoning_removes_most_of_a_lone_robots_latency_cost() -> None:
    # a single robot on an open 12 x 12 grid under two steps of latency, one hand-made
    # policy: step towards the goal (x first); eight start/goal pairs
    rng = np.random.default_rng(0)
    cells = rng.integers(0, 12, size=(1, 8, 1, 4))
    inst = MaifInstances(MaifConfig(name="open", num_robots=1, size=12, fs=2, num_maps=1,
                                    num_formations=8),
                         np.zeros((1, 12, 12), dtype=bool), cells[..., :2], cells[..., 2:])

    def lengths(cond: Conditions, reckon: bool, ids: list[int]) -> list[int]:
        b = len(ids)
        env = ConditionedEnv(MaifEnv(inst, num_envs=b, seed=0, instance_order="round_robin",
                                     instance_ids=ids, max_steps=100), cond)
        obs, _ = env.reset(seed=0)
        dr = DeadReckoner(b, grid_size=inst.config.size)
        out: dict[int, int] = {}
        while len(out) < b:
            o = obs.reshape(b, 57)
            if reckon:
                o = dr.correct(o, env.obs_age.reshape(-1))
            dx, dy = o[:, 4] - o[:, 0], o[:, 5] - o[:, 1]
            a = np.where(np.abs(dx) > 1e-4, np.where(dx > 0, 4, 3),
                         np.where(np.abs(dy) > 1e-4, np.where(dy > 0, 2, 1), 0))
            dr.record(a)
            res = env.step(a.reshape(b, 1))
            for ep in res.episodes:
                out.setdefault(ep.env_index, ep.length)
                dr.reset([ep.env_index])
            obs = res.obs
        return [out[i] for i in range(b)]

    ids = list(range(8))
    ideal = lengths(Conditions(), False, ids)
    assert max(ideal) < 100
    late = Conditions(latency=2)
    stale, reckoned = lengths(late, False, ids), lengths(late, True, ids)
    assert np.mean(reckoned) <= np.mean([ideal[i] for i in ids]) + 2.5
    assert np.mean(stale) > np.mean(reckoned) + 10


def test_actor_core_applies_dead_reckoning_to_a_stale_observation() -> None:
    rt = ActorRuntime.from_file("models/maif-tiny-sdhn/actor.safetensors")
    plain = ActorCore(0, 4, greedy=True, seed=0, runtime=rt)
    reck = ActorCore(0, 4, greedy=True, seed=0, runtime=rt, reckoner=DeadReckoner(1, 12))
    env = MaifEnv(load_instances("maif-tiny"), num_envs=1, seed=0)
    obs, _ = env.reset(seed=0)
    o = obs[0, 0]
    first = reck.on_obs(0, 0, 0, 4, o)
    assert isinstance(first, Decision) and first == plain.on_obs(0, 0, 0, 4, o)
    # the same stale observation again, one step old: the reckoning core moves it by the
    # action it sent, so it decides on a different input than the plain core does
    assert reck.reckoner is not None
    moved = reck.reckoner.correct(o[None], [1])[0]
    assert first.action == 0 or not np.array_equal(moved, o)
    assert isinstance(reck.on_obs(0, 1, 0, 4, o, obs_age=1), Decision)
