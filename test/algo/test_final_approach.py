"""sdhn_policy.final_approach against the world itself: observations of real MaifEnv states
(robots driven by the scripted greedy walker, with random moves mixed in, so many stand on or
next to their goals), random chosen actions and sampling flags; whatever the rule changes is checked
against the true positions, goals and obstacles, not against the window it reads."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_policy.final_approach import FinalApproach
from sdhn_sim.envs.maif import ACTION_DELTAS, OBS_SIZE, MaifEnv
from sdhn_sim.envs.maif_scripted import GreedyPolicy


def world_states(task: str, seed: int, steps: int, envs: int = 3
                 ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(obs [B*N, 57], positions [B*N, 2], goals [B*N, 2], obstacles [B, size, size]) after
    each of ``steps`` steps of mostly-greedy play."""
    env = MaifEnv(task, num_envs=envs, seed=seed)
    walker = GreedyPolicy(seed)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        b, n = env.num_envs, env.num_robots
        obstacles = np.stack([env.world(e).obstacles for e in range(b)])
        out.append((obs.reshape(b * n, -1).copy(), env.positions.reshape(b * n, 2).copy(),
                    env.goals.reshape(b * n, 2).copy(), obstacles))
        act = walker.act(obs)
        act = np.where(rng.random(act.shape) < 0.2, rng.integers(0, 5, act.shape), act)
        obs = env.step(act).obs
    return out


def free_in_world(cell: np.ndarray, positions: np.ndarray, obstacles: np.ndarray) -> bool:
    x, y = int(cell[0]), int(cell[1])
    size = obstacles.shape[0]
    if not (0 <= x < size and 0 <= y < size) or obstacles[y, x]:
        return False
    return not bool(np.any(np.all(positions == cell, axis=1)))


@settings(max_examples=12, deadline=None, derandomize=True)
@given(task=st.sampled_from(["maif-tiny", "maif-10"]), seed=st.integers(0, 10_000),
       draw_seed=st.integers(0, 10_000))
def test_capture_and_hold_against_the_true_world(task: str, seed: int, draw_seed: int) -> None:
    rule = FinalApproach.for_env(task)
    rng = np.random.default_rng(draw_seed)
    captured = held = 0
    steps = 60 if task == "maif-tiny" else 120  # maif-10's robots walk further
    for obs, pos, goal, obstacles in world_states(task, seed, steps):
        rows = len(obs)
        n = rows // len(obstacles)
        act = rng.integers(0, 5, rows)
        sampling = rng.random(rows) < 0.3
        got = rule.apply(obs, act, sampling)
        dist = np.abs(goal - pos).sum(axis=1)
        for i in range(rows):
            team = slice(i // n * n, i // n * n + n)
            goal_free = free_in_world(goal[i], pos[team], obstacles[i // n])
            if dist[i] == 1 and goal_free:  # capture: onto the goal, sampled step or not
                assert np.array_equal(pos[i] + ACTION_DELTAS[got[i]], goal[i]), (i, got[i])
                captured += 1
            elif dist[i] == 0 and not sampling[i]:  # hold
                assert got[i] == 0
                held += 1
            else:  # one cell off with the goal taken, on it while sampling, or farther
                assert got[i] == act[i], (i, dist[i], goal_free, sampling[i])
            if got[i] != act[i] and got[i] != 0:  # any move the rule makes: into a free cell
                assert free_in_world(pos[i] + ACTION_DELTAS[got[i]], pos[team],
                                     obstacles[i // n])
    assert captured + held > 0, "the states never exercised the rule"


def test_rows_are_independent() -> None:
    rule = FinalApproach.for_env("maif-10")
    states = world_states("maif-10", seed=4, steps=60)
    obs = np.concatenate([s[0] for s in states])
    rng = np.random.default_rng(1)
    act, sampling = rng.integers(0, 5, len(obs)), rng.random(len(obs)) < 0.5
    batch = rule.apply(obs, act, sampling)
    one = np.array([rule.apply(obs[i:i + 1], act[i:i + 1], sampling[i:i + 1])[0]
                    for i in range(len(obs))])
    assert np.array_equal(batch, one)
    perm = rng.permutation(len(obs))
    assert np.array_equal(rule.apply(obs[perm], act[perm], sampling[perm]), batch[perm])
    assert np.any(batch != act), "the rule changed nothing: the comparison proved nothing"


def test_the_goal_offset_reads_cells_on_every_grid() -> None:
    """A robot at (x, y) and its goal one cell to each side, on grids of several sizes."""
    for size in (12, 32, 151):
        rule = FinalApproach(size)
        o = np.zeros((4, OBS_SIZE), dtype=np.float32)
        x, y = size // 2, size // 2
        o[:, 0:2] = np.array([x, y], dtype=np.float32) / (size - 1)
        goals = [(x, y - 1), (x, y + 1), (x - 1, y), (x + 1, y)]  # up, down, left, right
        o[:, 4:6] = np.array(goals, dtype=np.float32) / (size - 1)
        assert rule.apply(o, np.zeros(4, np.int64), np.zeros(4, bool)).tolist() == [1, 2, 3, 4]
        two_off = o.copy()
        two_off[:, 4:6] = np.array([(x, y - 2), (x + 1, y + 1), (x - 2, y), (x + 2, y)],
                                   dtype=np.float32) / (size - 1)
        assert rule.apply(two_off, np.full(4, 3), np.zeros(4, bool)).tolist() == [3] * 4


def test_for_env_and_bad_input() -> None:
    assert FinalApproach.for_env("maif-100").size == 152  # maif-40's density: 19 x 8 cells
    for name in ("rware-3", "maif-7"):
        with pytest.raises(ValueError, match="not a MAIF grid; allowed"):
            FinalApproach.for_env(name)
    with pytest.raises(ValueError, match="grid size"):
        FinalApproach(1)
    with pytest.raises(ValueError, match="expected obs"):
        FinalApproach(12).apply(np.zeros((2, 10)), np.zeros(2), np.zeros(2, bool))
