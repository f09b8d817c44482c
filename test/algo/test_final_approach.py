"""sdhn_policy.final_approach against the world itself: observations of real MaifEnv states
(robots driven by the scripted greedy walker, with random moves mixed in, so many stand on or
next to their goals), random chosen actions and sampling flags; whatever the rule changes is checked
against the true positions, goals and obstacles, not against the window it reads."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_policy.final_approach import FinalApproach
from sdhn_sim.envs.maif import ACTION_DELTAS, OBS_SIZE, RADIUS, MaifEnv
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


def world_path_step(pos: np.ndarray, goal: np.ndarray, positions: np.ndarray,
                    obstacles: np.ndarray) -> int | None:
    """The path rule worked out on the world itself: breadth-first from the goal over the free
    cells within RADIUS of the robot (Chebyshev), the robot's own cell included; the first of up,
    down, left, right one step closer, or None where the goal is taken or cut off."""
    def usable(cell: tuple[int, int]) -> bool:
        c = np.array(cell)
        return bool(np.abs(c - pos).max() <= RADIUS) and (
            bool(np.array_equal(c, pos)) or free_in_world(c, positions, obstacles))

    start = (int(goal[0]), int(goal[1]))
    if not usable(start):
        return None
    dist = {start: 0}
    frontier = [start]
    while frontier:
        nxt = []
        for x, y in frontier:
            for dx, dy in ACTION_DELTAS[1:]:
                cell = (x + int(dx), y + int(dy))
                if cell not in dist and usable(cell):
                    dist[cell] = dist[(x, y)] + 1
                    nxt.append(cell)
        frontier = nxt
    here = (int(pos[0]), int(pos[1]))
    if here not in dist:
        return None
    for a in (1, 2, 3, 4):
        cell = (here[0] + int(ACTION_DELTAS[a][0]), here[1] + int(ACTION_DELTAS[a][1]))
        if dist.get(cell) == dist[here] - 1:
            return a
    raise AssertionError("a reached cell always has a neighbour one step closer")


@settings(max_examples=12, deadline=None, derandomize=True)
@given(task=st.sampled_from(["maif-tiny", "maif-10"]), seed=st.integers(0, 10_000),
       draw_seed=st.integers(0, 10_000))
def test_capture_and_hold_against_the_true_world(task: str, seed: int, draw_seed: int) -> None:
    rule = FinalApproach.for_env(task)
    rng = np.random.default_rng(draw_seed)
    captured = held = walked = 0
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
            elif (dist[i] >= 2 and np.abs(goal[i] - pos[i]).max() <= RADIUS
                  and not sampling[i]):  # path: as the true world's window cells allow
                want = world_path_step(pos[i], goal[i], pos[team], obstacles[i // n])
                assert got[i] == (act[i] if want is None else want), (i, got[i], want)
                walked += want is not None
            else:  # one cell off with the goal taken, on it while sampling, or out of view
                assert got[i] == act[i], (i, dist[i], goal_free, sampling[i])
            if got[i] != act[i] and got[i] != 0:  # any move the rule makes: into a free cell
                assert free_in_world(pos[i] + ACTION_DELTAS[got[i]], pos[team],
                                     obstacles[i // n])
    assert captured + held > 0, "the states never exercised the rule"
    assert walked > 0, "no robot took a path step: the path rule went unchecked"


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
        # two cells off in an empty window: the path's first step (down before right on a tie)
        assert rule.apply(two_off, np.full(4, 3), np.zeros(4, bool)).tolist() == [1, 2, 3, 4]
        assert rule.apply(two_off, np.full(4, 3), np.ones(4, bool)).tolist() == [3] * 4
        out_of_view = o.copy()
        out_of_view[:, 4:6] = np.array([(x, y - 4), (x + 4, y + 1), (x - 4, y), (x + 4, y)],
                                       dtype=np.float32) / (size - 1)
        assert rule.apply(out_of_view, np.full(4, 3), np.zeros(4, bool)).tolist() == [3] * 4


def test_for_env_and_bad_input() -> None:
    assert FinalApproach.for_env("maif-100").size == 152  # maif-40's density: 19 x 8 cells
    for name in ("rware-3", "maif-7"):
        with pytest.raises(ValueError, match="not a MAIF grid; allowed"):
            FinalApproach.for_env(name)
    with pytest.raises(ValueError, match="grid size"):
        FinalApproach(1)
    with pytest.raises(ValueError, match="expected obs"):
        FinalApproach(12).apply(np.zeros((2, 10)), np.zeros(2), np.zeros(2, bool))


class PerRobotDraws:
    """The runtime with each robot's draws from its own generator, ``[seed, robot_id]`` as each
    ActorCore has, and only for the rows the breaker samples (as each actor process draws), so
    the batched path can be compared with the cores exactly, sampled steps included."""

    def __init__(self, rt: Any, breaker: Any, n: int, seed: int) -> None:
        self.rt, self.breaker = rt, breaker
        self.rngs = [np.random.default_rng([seed, i]) for i in range(n)]

    def act(self, obs: Any, hidden: Any, greedy: bool, rng: np.random.Generator,
            robot_id: Any = None, *, temperature: float = 1.0) -> tuple[Any, Any, Any]:
        act, logp, h = self.rt.act(obs, hidden, True, rng, robot_id)
        if not greedy:
            for i in np.flatnonzero(self.breaker.sampling):
                a, _, _ = self.rt.act(obs[i:i + 1], hidden[i:i + 1], False, self.rngs[i],
                                      temperature=temperature)
                act[i] = a[0]
        return act, logp, h


def test_actor_core_and_the_batched_evaluation_take_the_same_actions() -> None:
    """One ActorCore per robot (as each actor process runs it) against the batched step of
    ``heldout_eval.evaluate_set`` (greedy, ``StallBreaker.resample``, then the rule on its
    ``sampling`` mask) on the same observations, with the same random streams: the same action
    for every robot at every step. The maif-20 actor on maif-30, where the rule fires often."""
    from pathlib import Path

    from sdhn_policy.actor_core import ActorCore, Decision
    from sdhn_policy.actor_runtime import ActorRuntime
    from sdhn_policy.stall_breaker import StallBreaker, StallRule

    actor = Path(__file__).resolve().parents[2] / "models" / "maif-20-sdhn" / "actor.safetensors"
    rt = ActorRuntime.from_file(actor)
    rule, task = StallRule.parse("2,10,2"), "maif-30"
    approach = FinalApproach.for_env(task)
    env = MaifEnv(task, num_envs=1, seed=4, max_steps=150)
    n = env.num_robots
    cores = [ActorCore(i, n, True, 0, rt, stall_rule=rule, approach=approach) for i in range(n)]
    breaker, h = StallBreaker(rule, n), rt.initial_state(n)
    policy = PerRobotDraws(rt, breaker, n, seed=0)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=4)
    overridden = sampled = 0
    for step in range(150):
        flat = obs.reshape(n, -1)
        ours = [c.on_obs(0, step, i, n, flat[i]) for i, c in enumerate(cores)]
        assert all(isinstance(d, Decision) for d in ours)
        one = np.array([d.action for d in ours if isinstance(d, Decision)])
        greedy, _, h_next = rt.act(flat, h, True, rng)
        drawn = breaker.resample(policy, flat, h, greedy, rng=rng)
        batch = approach.apply(flat, drawn, breaker.sampling)
        h = h_next
        assert np.array_equal(one, batch), (step, one, batch)
        overridden += int(np.sum(batch != drawn))
        sampled += int(breaker.sampling.sum())
        res = env.step(one[None])
        if res.episodes:
            break
        obs = res.obs
    assert overridden > 0 and sampled > 0, (overridden, sampled)


def test_actor_core_refuses_the_rule_without_stall_breaking() -> None:
    from sdhn_policy.actor_core import ActorCore

    with pytest.raises(ValueError, match="requires stall breaking"):
        ActorCore(0, 4, greedy=True, seed=0, approach=FinalApproach(12))
