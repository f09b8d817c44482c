"""Scripted RWARE policies, the yardsticks a learner on RWARE is judged against (no torch).

- ``RandomPolicy``: every robot draws one of the 5 actions uniformly (seeded). What an untrained
  learner does, roughly.
- ``ScriptedPolicy`` (**centralised**): reads every rware ``Warehouse``'s state (robot poses and
  loads, where each shelf stands, the request queue), not the robots' observations, so it is a
  yardstick of what the task allows, not a decentralised policy. Each robot runs the RWARE job
  as a state machine:

  1. empty-handed: drive to a requested shelf no other robot carries or is heading to (pairs
     claimed nearest-first), stand under it, ``toggle_load``;
  2. carrying a requested shelf: drive to a goal (the delivery happens on arrival, rware then
     replaces the request);
  3. carrying any other shelf (just delivered): drive to the nearest empty shelf location (a
     non-highway cell without a shelf), ``toggle_load`` to put it down; back to 1.

  Driving: a BFS from the target cells over the cells the robot may enter (a loaded robot cannot
  enter a cell with a standing shelf; an empty one passes under shelves), with the other robots'
  cells blocked so it routes around them; if that finds no way it ignores the robots and waits
  when the next cell is taken. The robot turns towards the next cell (rware robots turn in place,
  then move forward). Collision handling beyond that is rware's own (a conflicting move is
  cancelled); a robot that has not moved for ``patience`` steps while trying to takes a random
  action with probability 1/2 — that breaks head-on deadlocks. Seeded, so deterministic.

``run_episodes(env, policy, seed)`` plays the first episode of each of the B environments and
returns their ``EpisodeStats``. RWARE's registered tasks pay rware's own *individual* reward:
+1 to the robot on the goal for each requested shelf delivered and nothing else, so an episode's
team return **is** its number of deliveries (``test_rware_scripted`` checks this against rware's
request queue).
"""

from __future__ import annotations

from collections import deque
from typing import Any, Protocol

import numpy as np

from .api import BatchedEnv, EpisodeStats, FloatArray, IntArray
from .rware_env import NUM_ACTIONS, RwareEnv

NOOP, FORWARD, LEFT, RIGHT, TOGGLE = range(NUM_ACTIONS)
# rware's Direction values: UP 0, DOWN 1, LEFT 2, RIGHT 3, as (dx, dy) cell offsets
_STEP = {0: (0, -1), 1: (0, 1), 2: (-1, 0), 3: (1, 0)}
# rware turns through this clockwise order: RIGHT is +1, LEFT is -1
_CLOCKWISE = (0, 3, 1, 2)


def turn_towards(facing: int, want: int) -> int:
    """The action that brings a robot facing ``facing`` closer to facing ``want`` (FORWARD if it
    already does)."""
    k = (_CLOCKWISE.index(want) - _CLOCKWISE.index(facing)) % 4
    return FORWARD if k == 0 else LEFT if k == 3 else RIGHT


def bfs_from(targets: list[tuple[int, int]], passable: np.ndarray) -> np.ndarray:
    """Steps from every cell to the nearest of ``targets`` over ``passable`` [H, W]
    (-1 = unreachable). Targets themselves count as reachable even if not passable."""
    h, w = passable.shape
    dist = np.full((h, w), -1, dtype=np.int64)
    q: deque[tuple[int, int]] = deque()
    for x, y in targets:
        if dist[y, x] < 0:
            dist[y, x] = 0
            q.append((x, y))
    while q:
        x, y = q.popleft()
        d = dist[y, x] + 1
        for dx, dy in _STEP.values():
            nx, ny = x + dx, y + dy
            if 0 <= nx < w and 0 <= ny < h and dist[ny, nx] < 0 and passable[ny, nx]:
                dist[ny, nx] = d
                q.append((nx, ny))
    return dist


class RandomPolicy:
    """Uniform over the 5 rware actions for every robot, from its own generator."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: FloatArray) -> IntArray:
        return self.rng.integers(0, NUM_ACTIONS, size=obs.shape[:2], dtype=np.int64)


class ScriptedPolicy:
    """Centralised fetch-deliver-return heuristic; call ``act(env)`` before each ``env.step``."""

    def __init__(self, seed: int = 0, patience: int = 3) -> None:
        self.rng = np.random.default_rng(seed)
        self.patience = patience
        # per (env, robot): the pose last seen and for how many steps it has not changed
        self._last: dict[tuple[int, int], tuple[int, int, int]] = {}
        self._still: dict[tuple[int, int], int] = {}

    def act(self, env: RwareEnv) -> IntArray:
        actions = np.zeros((env.num_envs, env.num_robots), dtype=np.int64)
        for b, wh in enumerate(env.warehouses):
            actions[b] = self._act_one(b, wh)
        return actions

    def _act_one(self, b: int, wh: Any) -> list[int]:
        # [H, W] shelf id at each cell where a shelf stands, 0 = none. rware's shelf layer also
        # holds the carried shelves, under their robots: those cells are not taken (a loaded
        # robot never stands on a standing shelf, so nothing else is cleared)
        shelf_at = wh.grid[1].copy()
        for a in wh.agents:
            if a.carrying_shelf is not None:
                shelf_at[a.y, a.x] = 0
        agents = wh.agents
        occupied = {(a.x, a.y) for a in agents}
        targets = self._targets(wh, shelf_at)
        out = []
        for i, a in enumerate(agents):
            goal = targets[i]
            if goal is None:
                act = NOOP
            elif (a.x, a.y) in goal[0]:
                act = goal[1]
            else:
                act = self._drive(a, goal[0], occupied, shelf_at, loaded=a.carrying_shelf
                                  is not None)
            out.append(self._unstick(b, i, a, act))
        return out

    @staticmethod
    def _targets(wh: Any, shelf_at: np.ndarray) -> list[tuple[list[tuple[int, int]], int] | None]:
        """Per robot: (target cells, action to take on arrival), or None (nothing to do)."""
        agents = wh.agents
        highway = wh.highways.astype(bool)
        carried = {id(a.carrying_shelf) for a in agents if a.carrying_shelf is not None}
        requested = {id(s) for s in wh.request_queue}
        out: list[tuple[list[tuple[int, int]], int] | None] = [None] * len(agents)
        goals = [(int(x), int(y)) for x, y in wh.goals]
        empty = [(int(x), int(y)) for y, x in zip(*np.nonzero(~highway & (shelf_at == 0)),
                                                  strict=True)]
        free_requests = [s for s in wh.request_queue if id(s) not in carried]
        idle = []
        for i, a in enumerate(agents):
            if a.carrying_shelf is None:
                idle.append(i)
            elif id(a.carrying_shelf) in requested:
                out[i] = (goals, NOOP)  # rware counts the delivery on arrival
            else:
                out[i] = (empty, TOGGLE)
        # empty-handed robots claim requested shelves, the nearest (L1) robot-shelf pair first
        pairs = sorted((abs(agents[i].x - s.x) + abs(agents[i].y - s.y), i, k)
                       for i in idle for k, s in enumerate(free_requests))
        taken: set[int] = set()
        for _, i, k in pairs:
            if out[i] is None and k not in taken:
                taken.add(k)
                s = free_requests[k]
                out[i] = ([(int(s.x), int(s.y))], TOGGLE)
        return out

    def _drive(self, a: Any, cells: list[tuple[int, int]], occupied: set[tuple[int, int]],
               shelf_at: np.ndarray, *, loaded: bool) -> int:
        # a loaded robot may not enter a cell where a shelf stands; an empty one passes under
        passable = (shelf_at == 0) if loaded else np.ones(shelf_at.shape, dtype=bool)
        others = occupied - {(a.x, a.y)}
        around = passable.copy()
        for x, y in others:
            around[y, x] = False
        dist = bfs_from([c for c in cells if c not in others], around)
        if dist[a.y, a.x] < 0:  # no way around the robots: head straight, wait when blocked
            for x, y in others:
                passable[y, x] = True
            dist = bfs_from(cells, passable)
            if dist[a.y, a.x] < 0:
                return NOOP
        d = dist[a.y, a.x]
        facing = a.dir.value
        best: tuple[int, int] | None = None  # (turns needed, direction)
        h, w = dist.shape
        for want, (dx, dy) in _STEP.items():
            nx, ny = a.x + dx, a.y + dy
            if 0 <= nx < w and 0 <= ny < h and dist[ny, nx] == d - 1:
                k = (_CLOCKWISE.index(want) - _CLOCKWISE.index(facing)) % 4
                turns = min(k, 4 - k)
                if best is None or turns < best[0]:
                    best = (turns, want)
        if best is None:
            return NOOP
        act = turn_towards(facing, best[1])
        dx, dy = _STEP[best[1]]
        if act == FORWARD and (a.x + dx, a.y + dy) in others:
            return NOOP
        return act

    def _unstick(self, b: int, i: int, a: Any, act: int) -> int:
        """Count steps without a pose change while trying to move; past ``patience``, take a
        random action half of the time (breaks deadlocks rware's conflict rule creates)."""
        pose = (int(a.x), int(a.y), int(a.dir.value))
        key = (b, i)
        still = self._still.get(key, 0) + 1 if self._last.get(key) == pose else 0
        self._last[key] = pose
        self._still[key] = still
        if act in (FORWARD, NOOP) and still >= self.patience and self.rng.random() < 0.5:
            return int(self.rng.integers(FORWARD, TOGGLE))  # forward, left or right
        return act


class ObsPolicy(Protocol):
    """A policy acting on the robots' observations [B, N, D] alone."""

    def act(self, obs: FloatArray) -> IntArray: ...


def run_episodes(env: BatchedEnv, policy: ScriptedPolicy | ObsPolicy,
                 seed: int | None = None) -> list[EpisodeStats]:
    """The first episode of each of the B environments (env b from seed ``seed + b``), by env
    index. The centralised ``ScriptedPolicy`` needs the real rware backend (``RwareEnv``)."""
    obs, _ = env.reset(seed=seed)
    first: dict[int, EpisodeStats] = {}
    while len(first) < env.num_envs:
        if isinstance(policy, ScriptedPolicy):
            if not isinstance(env, RwareEnv):
                raise TypeError("the centralised ScriptedPolicy reads rware's Warehouse objects: "
                                "build the env with backend='rware'")
            a = policy.act(env)
        else:
            a = policy.act(obs)
        res = env.step(a)
        obs = res.obs
        for ep in res.episodes:
            first.setdefault(ep.env_index, ep)
    return [first[k] for k in sorted(first)]
