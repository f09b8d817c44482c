"""Scripted MAIF policies, the yardsticks a learned policy is judged against (NumPy, no torch).

- ``GreedyPolicy`` (decentralised): each robot uses only its own 57-float observation. It steps
  towards its goal along an axis that shrinks the L1 distance (random tie-break, weighted by the
  remaining offset on each axis), never into a cell its window shows as an obstacle, wall or robot;
  when every such move is blocked it sidesteps into a free cell with probability ``sidestep``, else
  waits. On its goal it stays.
- ``PlannerPolicy`` (centralised): knows the map, every start and goal. Prioritized planning
  (robots whose goal lies deepest in the goal corner first) with a space-time A* per robot on
  BFS distances, avoiding the vertex and swap reservations of earlier robots and their parked
  goals; a robot parks on its goal only when no earlier robot passes it later. The plan runs
  through the real environment; if the environment's conflict rules ever stop a robot, or a robot
  finds no plan, everyone replans from where they stand (in a shuffled order after a failure).

``run_episodes(env, policy)`` plays one episode in each of the B environments and returns their
``EpisodeStats`` (use ``instance_order="round_robin"`` and B = number of instances to cover a set).
``lower_bound(env)`` is the mean over the B instances of the longest single-robot shortest path.
``evaluate_scripted(task, which, policy)`` does all of it on instances 0..k-1 of one instance set:
the one evaluation behind ``scripts/eval_scripted.py``, ``scripts/ship_model.py`` and the scripted
rows of ``make_figures``.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from .api import EpisodeStats, FloatArray, IntArray
from .maif import ACTION_DELTAS, COORD_FEATURES, WINDOW, MaifEnv, MaifWorld
from .maif_instances import MAIF_CONFIGS
from .registry import make_env

_CENTRE = (WINDOW * WINDOW) // 2
# flat window index of the cell each action (stay, up, down, left, right) leads to
_NEIGHBOUR = _CENTRE + ACTION_DELTAS[:, 0] + ACTION_DELTAS[:, 1] * WINDOW


class GreedyPolicy:
    """Decentralised: actions [B, N] from observations [B, N, 57] only."""

    def __init__(self, seed: int = 0, sidestep: float = 0.5) -> None:
        self.rng = np.random.default_rng(seed)
        self.sidestep = sidestep

    def act(self, obs: FloatArray) -> IntArray:
        o = np.asarray(obs)
        dx, dy = o[..., 4] - o[..., 0], o[..., 5] - o[..., 1]
        free = o[..., COORD_FEATURES + _NEIGHBOUR] == 0  # [..., 5]; stay is always "free"
        eps = 1e-6
        # how much each move shrinks the distance (>0 only for moves towards the goal)
        toward = np.stack([np.zeros_like(dx), np.maximum(-dy, 0), np.maximum(dy, 0),
                           np.maximum(-dx, 0), np.maximum(dx, 0)], axis=-1)
        toward[..., 1:] = np.where(toward[..., 1:] > eps, toward[..., 1:] + 0.5, 0.0)
        u = self.rng.random(toward.shape)
        score = np.where(free & (toward > 0), toward * u, -np.inf)
        best = score.argmax(axis=-1)
        ok = np.isfinite(score.max(axis=-1))
        # blocked towards the goal: sidestep into a random free cell, or wait
        side = np.where(free[..., 1:], self.rng.random(free[..., 1:].shape), -1.0)
        side_a = side.argmax(axis=-1) + 1
        can_side = (side.max(axis=-1) >= 0) & (self.rng.random(dx.shape) < self.sidestep)
        action = np.where(ok, best, np.where(can_side, side_a, 0))
        on_goal = (np.abs(dx) + np.abs(dy)) < eps
        return np.where(on_goal, 0, action).astype(np.int64)


def bfs_distances(free: npt.NDArray[np.bool_], gx: int, gy: int) -> npt.NDArray[np.int64]:
    """Shortest 4-connected path length from every cell to (gx, gy) over ``free``; -1 = none."""
    s = free.shape[0]
    dist = np.full(free.shape, -1, dtype=np.int64)
    dist[gy, gx] = 0
    q = deque([(gx, gy)])
    while q:
        x, y = q.popleft()
        d = dist[y, x] + 1
        for ddx, ddy in ((0, -1), (0, 1), (-1, 0), (1, 0)):
            nx, ny = x + ddx, y + ddy
            if 0 <= nx < s and 0 <= ny < s and free[ny, nx] and dist[ny, nx] < 0:
                dist[ny, nx] = d
                q.append((nx, ny))
    return dist


class _Reservations:
    """Space-time reservations of the robots planned so far (cells are flat ints)."""

    def __init__(self) -> None:
        self.vertex: set[tuple[int, int]] = set()  # (cell, t)
        self.edge: set[tuple[int, int, int]] = set()  # (from, to, t): moved from -> to at t
        self.parked: dict[int, int] = {}  # cell -> t from which a robot stays there forever
        self.last: dict[int, int] = {}  # cell -> latest t it is reserved at

    def blocked(self, cell: int, t: int) -> bool:
        p = self.parked.get(cell)
        return (cell, t) in self.vertex or (p is not None and t >= p)

    def add(self, path: list[int]) -> None:
        for t, c in enumerate(path):
            self.vertex.add((c, t))
            self.last[c] = max(self.last.get(c, -1), t)
            if t:
                self.edge.add((path[t - 1], c, t))
        self.parked[path[-1]] = len(path) - 1


def _astar(start: int, goal: int, size: int, *, free_flat: npt.NDArray[np.bool_],
           h: npt.NDArray[np.int64], res: _Reservations, horizon: int) -> list[int] | None:
    """Shortest space-time path start -> goal (parked there for good) avoiding ``res``."""
    if h[start] < 0:
        return None
    moves = (0, -size, size, -1, 1)
    tie = itertools.count()
    open_: list[tuple[int, int, int, int, int]] = [(int(h[start]), 0, next(tie), start, 0)]
    parent: dict[tuple[int, int], tuple[int, int] | None] = {(start, 0): None}
    while open_:
        _, _, _, cell, t = heapq.heappop(open_)
        if cell == goal and t > res.last.get(goal, -1):
            path = [cell]
            key: tuple[int, int] | None = (cell, t)
            while True:
                assert key is not None
                key = parent[key]
                if key is None:
                    break
                path.append(key[0])
            return path[::-1]
        if t >= horizon:
            continue
        x = cell % size
        for m in moves:
            nxt = cell + m
            if (m == -1 and x == 0) or (m == 1 and x == size - 1):
                continue
            if nxt < 0 or nxt >= free_flat.size or not free_flat[nxt] or h[nxt] < 0:
                continue
            nt = t + 1
            if (nxt, nt) in parent or res.blocked(nxt, nt) or (nxt, cell, nt) in res.edge:
                continue
            parent[(nxt, nt)] = (cell, t)
            heapq.heappush(open_, (nt + int(h[nxt]), int(h[nxt]), next(tie), nxt, nt))
    return None


def plan_paths(obstacles: npt.NDArray[np.bool_], positions: IntArray, goals: IntArray,
               order: list[int], horizon: int, *,
               dist_cache: dict[tuple[int, int], npt.NDArray[np.int64]] | None = None
               ) -> tuple[list[list[int]], bool]:
    """Prioritized planning; (flat-cell paths per robot, every robot found a path). A robot
    without a path waits where it is (and is reserved there)."""
    size = obstacles.shape[0]
    free = ~obstacles
    free_flat = free.reshape(-1)
    cache = {} if dist_cache is None else dist_cache
    res = _Reservations()
    paths: list[list[int]] = [[] for _ in range(len(positions))]
    ok = True
    for i in order:
        gx, gy = int(goals[i, 0]), int(goals[i, 1])
        if (gx, gy) not in cache:
            cache[(gx, gy)] = bfs_distances(free, gx, gy).reshape(-1)
        start = int(positions[i, 1]) * size + int(positions[i, 0])
        path = _astar(start, gy * size + gx, size, free_flat=free_flat, h=cache[(gx, gy)],
                      res=res, horizon=horizon)
        if path is None:
            ok = False
            path = [start]
        paths[i] = path
        res.add(path)
    return paths, ok


def _flat(cell: npt.NDArray[np.int64], size: int) -> int:
    return int(cell[1]) * size + int(cell[0])


class PlannerView(Protocol):
    """What the planner reads of the world: a ``MaifEnv``, or a view of one that shows the
    robots elsewhere (``condition_eval``: where a delayed observation saw them)."""

    size: int
    num_envs: int
    num_robots: int
    instances: Any

    @property
    def positions(self) -> IntArray: ...

    @property
    def step_count(self) -> IntArray: ...

    def world(self, b: int = 0) -> MaifWorld: ...


class PlannerPolicy:
    """Centralised: per environment, a prioritized plan executed in the real env (replanned on
    any deviation). Call ``act(env)`` before each ``env.step`` (``env``: the ``MaifEnv``, or a
    ``PlannerView`` of it)."""

    def __init__(self, seed: int = 0, slack: int = 60, attempts: int = 3) -> None:
        self.rng = np.random.default_rng(seed)
        self.slack = slack
        self.attempts = attempts
        self._plans: dict[int, tuple[list[list[int]], int]] = {}  # env -> (paths, t0)
        self._failed: dict[int, bool] = {}
        self._cache: dict[tuple[int, int], dict[tuple[int, int], npt.NDArray[np.int64]]] = {}

    def _replan(self, env: PlannerView, b: int) -> None:
        w = env.world(b)
        n = len(w.positions)
        if self._failed.get(b):
            order = [int(i) for i in self.rng.permutation(n)]
        else:  # deepest goal first: the leaders of the formation move out of the way
            order = sorted(range(n), key=lambda i: -int(w.goals[i].sum()))
        cache = self._cache.setdefault((w.instance_id, id(env.instances)), {})
        horizon = 2 * env.size + self.slack
        for _attempt in range(self.attempts):
            paths, ok = plan_paths(w.obstacles, w.positions, w.goals, order, horizon,
                                   dist_cache=cache)
            if ok:
                break
            # bump the robots that found no path to the front (priority bumping)
            stuck = [i for i in order if len(paths[i]) == 1 and paths[i][0] != _flat(w.goals[i],
                                                                                      env.size)]
            order = stuck + [i for i in order if i not in stuck]
        self._failed[b] = not ok
        self._plans[b] = (paths, w.step)

    def act(self, env: PlannerView) -> IntArray:
        size = env.size
        pos = env.positions  # [B, N, 2]
        steps = env.step_count
        actions = np.zeros((env.num_envs, env.num_robots), dtype=np.int64)
        for b in range(env.num_envs):
            t = int(steps[b])
            cur = pos[b, :, 1] * size + pos[b, :, 0]
            plan = self._plans.get(b)
            need = plan is None or t == 0 or t <= plan[1] or bool(self._failed.get(b))
            if plan is not None and not need:
                paths, t0 = plan
                need = cur.tolist() != [p[min(t - t0, len(p) - 1)] for p in paths]
            if need:
                self._replan(env, b)
            paths, t0 = self._plans[b]
            k = t - t0
            for i, p in enumerate(paths):
                if k + 1 < len(p):
                    d = p[k + 1] - p[k]
                    actions[b, i] = {0: 0, -size: 1, size: 2, -1: 3, 1: 4}[d]
        return actions


def run_episodes(env: MaifEnv, policy: GreedyPolicy | PlannerPolicy,
                 seed: int | None = None) -> list[EpisodeStats]:
    """One episode per environment (the first one each finishes), by env index."""
    obs, _ = env.reset(seed=seed)
    first: dict[int, EpisodeStats] = {}
    for _ in range(env.max_steps):
        a = policy.act(obs) if isinstance(policy, GreedyPolicy) else policy.act(env)
        res = env.step(a)
        obs = res.obs
        for ep in res.episodes:
            first.setdefault(ep.env_index, ep)
        if len(first) == env.num_envs:
            break
    return [first[k] for k in sorted(first)]


def lower_bound(env: MaifEnv) -> float:
    """Mean over the B environments' current instances of max_i BFS distance(start_i, goal_i)."""
    out = []
    for b in range(env.num_envs):
        w = env.world(b)
        free = ~w.obstacles
        longest = 0
        for (sx, sy), (gx, gy) in zip(w.positions.tolist(), w.goals.tolist(), strict=True):
            longest = max(longest, int(bfs_distances(free, gx, gy)[sy, sx]))
        out.append(longest)
    return float(np.mean(out))


SCRIPTED_LABELS = {"greedy": "scripted greedy (decentralised)",
                   "planner": "scripted planner (centralised)"}


@dataclass(frozen=True)
class ScriptedResult:
    """A scripted policy on one instance set: success and makespan first (makespan None = NC,
    no episode completed), then the return under the reward named."""

    task: str
    instance_set: str
    policy: str
    success_rate: float
    makespan: float | None
    lower_bound: float
    episode_return: float
    reward: str
    collisions: float


def evaluate_scripted(task: str, which: str, policy: str, *, instances: int = 100, seed: int = 0,
                      reward: str = "corrected") -> ScriptedResult:
    """One episode per instance 0..instances-1 of set ``which`` ("train" or "heldout") at the
    task's own step limit, played by ``policy`` ("greedy" or "planner")."""
    if policy not in SCRIPTED_LABELS:
        raise ValueError(f"unknown scripted policy {policy!r}; known: {list(SCRIPTED_LABELS)}")
    if task not in MAIF_CONFIGS:
        raise ValueError(f"{task} is not a MAIF task: the scripted baselines play MAIF only")
    env = make_env(task, num_envs=instances, seed=seed, instance_order="round_robin",
                   instance_ids=list(range(instances)), instance_set=which, reward=reward)
    assert isinstance(env, MaifEnv)
    pol = GreedyPolicy(seed) if policy == "greedy" else PlannerPolicy(seed)
    eps = run_episodes(env, pol, seed=seed)
    env.reset(seed=seed)  # back to the instances' start positions, for the bound
    done = [e.makespan for e in eps if e.makespan is not None]
    return ScriptedResult(
        task=task, instance_set=which, policy=policy,
        success_rate=float(np.mean([e.completed for e in eps])),
        makespan=float(np.mean(done)) if done else None, lower_bound=lower_bound(env),
        episode_return=float(np.mean([e.episode_return for e in eps])), reward=reward,
        collisions=float(np.mean([e.collisions for e in eps])))
