"""Dead reckoning: a robot moves its own stale MAIF observation forward by the actions it sent.

A robot whose observation is ``d`` steps old (a slow perception pipeline, an asynchronous graph,
``latency`` in ``sdhn_sim.envs.conditions``) sees itself where it was ``d`` steps ago. Acting on
that, it re-issues moves it has already made, overshoots its goal and oscillates: with one step
of latency the shipped maif-10 policy's makespan triples, with two steps almost no episode
completes (issue 53). The robot knows the actions it sent since the observed step, so it can
predict where it stands now: each sent move is taken unless the window shows an obstacle (or the
grid's edge) in its way; the own position moves by the predicted displacement and the 7x7
window shifts with it (cells that come into view read as free; other robots stay where they
were seen). Goals and the team centroid are left as observed.

NumPy only; runs per robot in the actor (``ActorCore``, ``dead_reckon``) and batched in process::

    dr = DeadReckoner(rows=b * n, grid_size=32, horizon=4)
    seen = dr.correct(obs, age)      # obs [rows, 57] as received, age [rows] steps old
    ... act on seen ...
    dr.record(actions)               # [rows] the actions sent this step
    dr.reset(rows)                   # a new episode for these rows

An observation older than ``horizon`` steps is moved by the last ``horizon`` actions only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from sdhn_sim.envs.maif import ACTION_DELTAS, COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW

OBSTACLE = 1.0
HORIZON = 8  # unseen actions taken at most (an older observation moves by the last HORIZON)


class DeadReckoner:
    """Per-row history of sent actions and the correction of stale observations."""

    def __init__(self, rows: int, grid_size: int, horizon: int = HORIZON) -> None:
        if grid_size < 2:
            raise ValueError(f"dead reckoning grid_size: got {grid_size}; allowed: >= 2")
        if horizon < 1:
            raise ValueError(f"dead reckoning horizon: got {horizon}; allowed: >= 1")
        self.rows = rows
        self.grid_size = grid_size
        self.horizon = horizon
        self._sent = np.zeros((rows, horizon), dtype=np.int64)  # newest last
        self._count = np.zeros(rows, dtype=np.int64)  # actions recorded this episode

    def reset(self, rows: slice | Sequence[int] | None = None) -> None:
        sel: slice | npt.NDArray[np.intp] = (
            slice(None) if rows is None else rows if isinstance(rows, slice)
            else np.asarray(rows, dtype=np.intp))
        self._sent[sel] = 0
        self._count[sel] = 0

    def record(self, actions: npt.ArrayLike) -> None:
        a = np.asarray(actions, dtype=np.int64).reshape(self.rows)
        self._sent = np.roll(self._sent, -1, axis=1)
        self._sent[:, -1] = a
        self._count += 1

    def correct(self, obs: npt.ArrayLike, age: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Observations [rows, 57] received ``age`` [rows] steps old -> predicted current ones."""
        o = np.array(obs, dtype=np.float32, copy=True)
        if o.shape != (self.rows, OBS_SIZE):
            raise ValueError(f"dead reckoning reads MAIF observations: expected "
                             f"[{self.rows}, {OBS_SIZE}], got {list(o.shape)}")
        d = np.minimum(np.minimum(np.asarray(age, dtype=np.int64).reshape(self.rows),
                                  self._count), self.horizon)
        if not d.any():
            return o
        inv = 1.0 / (self.grid_size - 1)
        cell = np.rint(o[:, 0:2] / inv).astype(np.int64)  # (x, y) where the robot was seen
        win = o[:, COORD_FEATURES:].reshape(self.rows, WINDOW, WINDOW)  # [row, y, x]
        off = np.zeros((self.rows, 2), dtype=np.int64)  # predicted displacement (dx, dy)
        rows = np.arange(self.rows)
        for back in range(int(d.max()), 0, -1):  # oldest unseen action first
            use = d >= back
            a = self._sent[:, self.horizon - back]
            step = ACTION_DELTAS[a] * use[:, None]
            tgt = off + step
            wx, wy = tgt[:, 0] + RADIUS, tgt[:, 1] + RADIUS
            inside = (wx >= 0) & (wx < WINDOW) & (wy >= 0) & (wy < WINDOW)
            seen = win[rows, np.clip(wy, 0, WINDOW - 1), np.clip(wx, 0, WINDOW - 1)]
            on_grid = np.all((cell + tgt >= 0) & (cell + tgt < self.grid_size), axis=1)
            blocked = (inside & (seen == OBSTACLE)) | ~on_grid
            off = np.where(blocked[:, None], off, tgt)
        moved = np.any(off != 0, axis=1)
        if not moved.any():
            return o
        # Only the moved rows, encoded as the environment encodes a cell (an int64 cell times the
        # float32 1 / (size - 1)): a row rewritten with other rounding would differ in the last
        # bit, enough to flip a policy's argmax some steps later, so a batch and a lone robot
        # (the actor) would decide differently on the same history.
        pos = np.empty((self.rows, 2), dtype=np.float32)
        np.multiply(cell + off, np.float32(inv), out=pos)
        o[moved, 0:2] = pos[moved]
        # shift the window: the cell at (x, y) now shows what was seen at (x + dx, y + dy)
        ys, xs = np.meshgrid(np.arange(WINDOW), np.arange(WINDOW), indexing="ij")
        sy = ys[None] + off[:, 1, None, None]
        sx = xs[None] + off[:, 0, None, None]
        ok = (sy >= 0) & (sy < WINDOW) & (sx >= 0) & (sx < WINDOW)
        shifted = win[rows[:, None, None], np.clip(sy, 0, WINDOW - 1), np.clip(sx, 0, WINDOW - 1)]
        # outside the old window: free on the grid, an obstacle beyond its edge
        gx = cell[:, 0, None, None] + off[:, 0, None, None] + xs[None] - RADIUS
        gy = cell[:, 1, None, None] + off[:, 1, None, None] + ys[None] - RADIUS
        edge = (gx < 0) | (gx >= self.grid_size) | (gy < 0) | (gy >= self.grid_size)
        new = np.where(ok, shifted, np.where(edge, OBSTACLE, 0.0))
        new[:, RADIUS, RADIUS] = 0.0  # the robot's own cell
        o[:, COORD_FEATURES:] = np.where(moved[:, None], new.reshape(self.rows, -1),
                                         o[:, COORD_FEATURES:])
        return o
