"""A decentralised scripted RWARE policy: each robot acts on its own observation only (no torch).

What a robot uses: its own 71-float observation (rware's flattened vector: its cell, load and
heading, and the 3 x 3 cells around it: robots, shelves, requested shelves), its own memory (the
cell it took its shelf from, the requested shelf it is heading to, its patrol waypoint), its
index in the team (as a learner's robot id) and the warehouse's static floor plan (highways,
goals: the task, not its state). It does not see the request queue, other robots beyond its
window, or where shelves stand elsewhere. This is the yardstick a decentralised learned policy
can be held to; the centralised ``rware_scripted.ScriptedPolicy`` reads the whole warehouse.

Each robot:

1. empty-handed: patrols the vertical highways (every shelf column borders one, so the window
   sees every shelf), each robot from its own waypoint; heads for a requested shelf as soon as
   one is in its window (and remembers it), stands under it, ``toggle_load``;
2. carrying a requested shelf (its own cell reads "requested"): drives to the nearest goal over
   highways only (a loaded robot cannot pass standing shelves; highways never hold one);
3. carrying any other shelf (just delivered): drives back to the cell it took it from and puts
   it down.

Driving follows the static shortest-path field to the target (cached per target), takes the next
cell not holding a robot it sees, turns towards it and goes forward; a robot that has not moved
for ``patience`` steps takes a random move half of the time (breaks head-on deadlocks). A robot
whose cell jumps (a new episode) forgets its memory. Seeded, so deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .api import FloatArray, IntArray
from .rware_batched import Layout
from .rware_scripted import _CLOCKWISE, _STEP, FORWARD, NOOP, TOGGLE, bfs_from, turn_towards

Cell = tuple[int, int]
_SENSOR0, _PER_CELL = 8, 7  # rware's flattened layout: 8 self floats, 7 per window cell


@dataclass
class _Memory:
    cell: Cell | None = None  # where the robot stood last step
    home: Cell | None = None  # where it took its shelf from
    claim: Cell | None = None  # a requested shelf it saw and heads to
    waypoint: int = 0
    still: int = 0  # steps without moving while trying to


class DecentralisedPolicy:
    """Per-robot fetch-deliver-return from the robot's own observation; ``act(obs)``."""

    def __init__(self, layout: Layout, num_robots: int, seed: int = 0, patience: int = 3) -> None:
        self.layout = layout
        self.num_robots = num_robots
        self.patience = patience
        self.rng = np.random.default_rng(seed)
        h, w = layout.height, layout.width
        self._highway = layout.highway
        self._goals = [(int(x), int(y)) for x, y in layout.goals]
        columns = list(range(0, w, 3))
        top, bottom = 1, h - 3
        route: list[Cell] = []
        for k, x in enumerate(columns):  # a snake over the vertical highways
            route += [(x, top), (x, bottom)] if k % 2 == 0 else [(x, bottom), (x, top)]
        self._route = route
        self._memory: dict[tuple[int, int], _Memory] = {}
        self._fields = lru_cache(maxsize=512)(self._field)

    def _field(self, target: tuple[Cell, ...], loaded: bool) -> np.ndarray:
        """Steps to the nearest target cell; a loaded robot only over highways."""
        passable = self._highway.copy() if loaded else np.ones_like(self._highway)
        return bfs_from(list(target), passable)

    def forget(self, env: int) -> None:
        """A new episode in env ``env``: its robots start with no memory (as after a jump)."""
        for i in range(self.num_robots):
            self._memory.pop((env, i), None)

    def act(self, obs: FloatArray) -> IntArray:
        nb, n = obs.shape[:2]
        out = np.zeros((nb, n), dtype=np.int64)
        for b in range(nb):
            for i in range(n):
                out[b, i] = self._act_one(b, i, obs[b, i])
        return out

    def _act_one(self, b: int, i: int, o: np.ndarray) -> int:
        x, y = int(o[0]), int(o[1])
        loaded = o[2] > 0.5
        facing = int(np.argmax(o[3:7]))
        window = o[_SENSOR0:].reshape(-1, _PER_CELL)  # 9 cells, row-major around the robot
        mem = self._memory.setdefault((b, i), _Memory(waypoint=i * len(self._route)
                                                       // max(1, self.num_robots)))
        if mem.cell is not None and abs(mem.cell[0] - x) + abs(mem.cell[1] - y) > 1:
            mem = self._memory[(b, i)] = _Memory(waypoint=mem.waypoint)  # a new episode
        moved = mem.cell != (x, y)
        mem.cell = (x, y)
        robots, free_requests = set(), []
        for k, cell in enumerate(window):
            cx, cy = x + k % 3 - 1, y + k // 3 - 1
            if k != 4 and cell[0] > 0.5:
                robots.add((cx, cy))
            if cell[5] > 0.5 and cell[6] > 0.5 and (k == 4 or cell[0] < 0.5):
                free_requests.append((cx, cy))
        if loaded:
            if window[4, 6] > 0.5:  # the carried shelf is requested: deliver
                act = self._drive(x, y, facing, tuple(self._goals), robots, loaded=True)
            elif mem.home is not None and (x, y) == mem.home:
                act = TOGGLE
            else:
                if mem.home is None:
                    mem.home = self._nearest_storage(x, y)
                act = self._drive(x, y, facing, (mem.home,), robots, loaded=True)
        elif (x, y) in free_requests:
            mem.home, mem.claim = (x, y), None
            act = TOGGLE
        else:
            if free_requests:
                mem.claim = min(free_requests, key=lambda c: abs(c[0] - x) + abs(c[1] - y))
            elif mem.claim is not None and abs(mem.claim[0] - x) <= 1 and abs(
                    mem.claim[1] - y) <= 1:
                mem.claim = None  # in view and no longer a free requested shelf
            if mem.claim is not None:
                act = self._drive(x, y, facing, (mem.claim,), robots, loaded=False)
            else:
                if (x, y) == self._route[mem.waypoint]:
                    mem.waypoint = (mem.waypoint + 1) % len(self._route)
                act = self._drive(x, y, facing, (self._route[mem.waypoint],), robots,
                                  loaded=False)
        mem.still = 0 if moved else mem.still + 1
        if act in (FORWARD, NOOP) and mem.still >= self.patience and self.rng.random() < 0.5:
            return int(self.rng.integers(FORWARD, TOGGLE))  # forward, left or right
        return act

    def _nearest_storage(self, x: int, y: int) -> Cell:
        """A shelf cell to put a shelf down when the robot does not remember where it took it
        (it started loaded): the nearest non-highway cell, by the static map."""
        ys, xs = np.nonzero(~self._highway)
        k = int(np.argmin(np.abs(xs - x) + np.abs(ys - y)))
        return int(xs[k]), int(ys[k])

    def _drive(self, x: int, y: int, facing: int, target: tuple[Cell, ...], robots: set[Cell],
               *, loaded: bool) -> int:
        dist = self._fields(target, loaded)
        if dist[y, x] == 0:
            return NOOP
        h, w = dist.shape
        # the next cells on a shortest way; a loaded robot standing on a shelf cell (off the
        # highway field) steps to its nearest highway neighbour
        steps = {want: int(dist[y + dy, x + dx]) for want, (dx, dy) in _STEP.items()
                 if 0 <= x + dx < w and 0 <= y + dy < h and dist[y + dy, x + dx] >= 0}
        if not steps:
            return NOOP
        d = min(steps.values())
        if dist[y, x] > 0 and d != dist[y, x] - 1:
            return NOOP
        best: tuple[int, int] | None = None  # (turns needed, direction)
        for want, dd in steps.items():
            dx, dy = _STEP[want]
            if dd == d and (x + dx, y + dy) not in robots:
                k = (_CLOCKWISE.index(want) - _CLOCKWISE.index(facing)) % 4
                if best is None or min(k, 4 - k) < best[0]:
                    best = (min(k, 4 - k), want)
        if best is None:
            return NOOP
        return turn_towards(facing, best[1])
