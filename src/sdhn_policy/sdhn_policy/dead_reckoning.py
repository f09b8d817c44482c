"""Dead reckoning: a robot moves its own stale observation forward by the actions it sent.

A robot whose observation is ``d`` steps old (a slow perception pipeline, an asynchronous graph,
``latency`` in ``sdhn_sim.envs.conditions``) sees itself where it was ``d`` steps ago. Acting on
that, it re-issues moves it has already made. The robot knows the actions it sent since the
observed step, so it can predict its own state now and redraw the observation around it. Two
rules share the bookkeeping (``ActionHistory``: the last ``horizon`` actions of each row):

**MAIF** (``DeadReckoner``): with one step of latency the shipped maif-10 policy's makespan
triples, with two steps almost no episode completes (issue 53): it overshoots its goal and
oscillates. Each sent move is taken unless the window shows an obstacle (or the grid's edge) in
its way; the own position moves by the predicted displacement and the 7x7 window shifts with it
(cells that come into view read as free; other robots stay where they were seen). Goals and the
team centroid are left as observed.

**RWARE** (``RwareDeadReckoner``): rware's actions are relative to the robot's heading and load
(forward, turn left, turn right, toggle load), so on a stale observation a robot turns past its
target heading, moves along a heading it no longer has and toggles a load it already toggled:
every method delivers nothing at one step of latency. The rule replays rware's own rules
(``rware`` 2.0.0 ``Warehouse.step``, re-expressed in ``sdhn_sim.envs.rware_batched``) for the
robot alone: turns change the heading; FORWARD moves one cell along it, clamped at the grid's
edge, and a loaded robot is stopped by a shelf in the target cell; TOGGLE_LOAD picks up the
shelf under an empty-handed robot and puts a carried one down off the highways; a requested
shelf carried onto a goal is delivered (no longer requested). What it knows of the floor: the
window as seen, and beyond it what it remembers (``memory``, default): each cell as the newest
observation that showed it this episode showed it (shelf, requested), the static floor plan
where no observation did (a shelf, not requested, on every storage cell, none on the
highways). The memory matters where the robot drives back to the gap it took a shelf from: on
the plan every storage cell holds a shelf, so two steps stale the learned rware-3 policies drove
past the gap and toggled their shelf on a highway, where rware keeps it (measured: 1,190 of
1,240 toggles; deliveries 3.8 per episode with the plan, 15.9 with the memory). What it cannot
know, and assumes: other robots stay where they were seen and never block it (rware may stop
it behind a robot, or let a loaded robot pass a shelf another robot carries away); shelves
other robots moved since it saw them stand where it saw them; a request drawn since it saw a
shelf is not shown.

NumPy only; runs per robot in the actor (``ActorCore``) and batched in process::

    dr = DeadReckoner(rows=b * n, grid_size=32, horizon=4)        # or RwareDeadReckoner(rows,
    seen = dr.correct(obs, age)      # obs [rows, D] as received,  #     layout, sensor_range)
    ... act on seen ...              # age [rows] steps old
    dr.record(actions)               # [rows] the actions sent this step
    dr.reset(rows)                   # a new episode for these rows

An observation older than ``horizon`` steps is moved by the last ``horizon`` actions only; an
observation that is current (age 0), or whose unseen actions are all no-ops, is returned as it
came. The RWARE rule reads every observation received (``correct`` with age 0 too) to remember
the floor.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from sdhn_sim.envs.maif import ACTION_DELTAS, COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW
from sdhn_sim.envs.rware_batched import (
    _DXY,
    _TURN_LEFT,
    _TURN_RIGHT,
    FORWARD,
    LEFT,
    RIGHT,
    TOGGLE,
    Layout,
)

OBSTACLE = 1.0
HORIZON = 8  # unseen actions taken at most (an older observation moves by the last HORIZON)
Rows = slice | Iterable[int] | None


def select(rows: Rows) -> slice | npt.NDArray[np.intp]:
    """An index for ``rows`` (None: every row)."""
    if rows is None:
        return slice(None)
    return rows if isinstance(rows, slice) else np.asarray(list(rows), dtype=np.intp)


class ActionHistory:
    """The last ``horizon`` actions each row sent this episode, and how many it sent."""

    def __init__(self, rows: int, horizon: int = HORIZON) -> None:
        if horizon < 1:
            raise ValueError(f"dead reckoning horizon: got {horizon}; allowed: >= 1")
        self.rows = rows
        self.horizon = horizon
        self._sent = np.zeros((rows, horizon), dtype=np.int64)  # newest last
        self._count = np.zeros(rows, dtype=np.int64)  # actions recorded this episode

    def reset(self, rows: Rows = None) -> None:
        sel = select(rows)
        self._sent[sel] = 0
        self._count[sel] = 0

    def record(self, actions: npt.ArrayLike) -> None:
        a = np.asarray(actions, dtype=np.int64).reshape(self.rows)
        self._sent = np.roll(self._sent, -1, axis=1)
        self._sent[:, -1] = a
        self._count += 1

    def unseen(self, age: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """[rows] how many recorded actions an observation ``age`` [rows] steps old has not
        seen: its age, at most the actions sent this episode and the horizon."""
        d = np.asarray(age, dtype=np.int64).reshape(self.rows)
        return np.minimum(np.minimum(d, self._count), self.horizon)

    @property
    def count(self) -> npt.NDArray[np.int64]:
        """[rows] the actions each row sent this episode."""
        return self._count

    def sent(self, back: int) -> npt.NDArray[np.int64]:
        """[rows] the action each row sent ``back`` steps ago (1 = the last one)."""
        return self._sent[:, self.horizon - back]


class Reckoner:
    """What both rules share: the action history, and the rows and horizon it keeps."""

    obs_size: int  # the observations it reads

    def __init__(self, rows: int, horizon: int) -> None:
        self.history = ActionHistory(rows, horizon)
        self.rows = rows
        self.horizon = horizon

    def reset(self, rows: Rows = None) -> None:
        self.history.reset(rows)

    def record(self, actions: npt.ArrayLike) -> None:
        self.history.record(actions)

    def correct(self, obs: npt.ArrayLike, age: npt.ArrayLike) -> npt.NDArray[np.float32]:
        raise NotImplementedError


class DeadReckoner(Reckoner):
    """MAIF: the correction of stale observations by the moves sent since."""

    def __init__(self, rows: int, grid_size: int, horizon: int = HORIZON) -> None:
        if grid_size < 2:
            raise ValueError(f"dead reckoning grid_size: got {grid_size}; allowed: >= 2")
        super().__init__(rows, horizon)
        self.grid_size = grid_size
        self.obs_size = OBS_SIZE

    def correct(self, obs: npt.ArrayLike, age: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Observations [rows, 57] received ``age`` [rows] steps old -> predicted current ones."""
        o = np.array(obs, dtype=np.float32, copy=True)
        if o.shape != (self.rows, OBS_SIZE):
            raise ValueError(f"dead reckoning reads MAIF observations: expected "
                             f"[{self.rows}, {OBS_SIZE}], got {list(o.shape)}")
        d = self.history.unseen(age)
        if not d.any():
            return o
        inv = 1.0 / (self.grid_size - 1)
        cell = np.rint(o[:, 0:2] / inv).astype(np.int64)  # (x, y) where the robot was seen
        win = o[:, COORD_FEATURES:].reshape(self.rows, WINDOW, WINDOW)  # [row, y, x]
        off = np.zeros((self.rows, 2), dtype=np.int64)  # predicted displacement (dx, dy)
        rows = np.arange(self.rows)
        for back in range(int(d.max()), 0, -1):  # oldest unseen action first
            use = d >= back
            a = self.history.sent(back)
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


RWARE_SELF = 8  # x, y, loaded, heading one-hot (up, down, left, right), on highway
RWARE_CELL = 7  # per window cell: robot, its heading one-hot, shelf, requested shelf
_EMPTY_CELL = np.array([0, 1, 0, 0, 0, 0, 0], dtype=np.float32)  # rware's empty/outside cell


class RwareDeadReckoner(Reckoner):
    """RWARE: the robot's own cell, heading and load (and the shelf it carries) predicted from
    the actions sent since the observed step, the observation redrawn around it (see the module
    docstring for what it knows and what it assumes)."""

    def __init__(self, rows: int, layout: Layout, sensor_range: int = 1,
                 horizon: int = HORIZON, memory: bool = True) -> None:
        if sensor_range < 1:
            raise ValueError(f"dead reckoning sensor_range: got {sensor_range}; allowed: >= 1")
        super().__init__(rows, horizon)
        self.memory = memory
        self.layout = layout
        self.radius = sensor_range
        self.side = 2 * sensor_range + 1
        self.obs_size = RWARE_SELF + self.side ** 2 * RWARE_CELL
        self._highway = layout.highway
        self._goal = np.zeros_like(layout.highway)
        for gx, gy in layout.goals:
            self._goal[gy, gx] = True
        # what each row last saw of every cell's shelf this episode; the plan where unseen
        self._plan = np.broadcast_to(~layout.highway, (rows, *layout.highway.shape))
        self._shelf = self._plan.copy()
        self._req = np.zeros_like(self._shelf)
        # the step (in actions sent) of the newest observation remembered: an older one that
        # arrives later (random latency) does not overwrite it
        self._seen_at = np.full(rows, -1, dtype=np.int64)

    def reset(self, rows: Rows = None) -> None:
        super().reset(rows)
        sel = select(rows)
        self._shelf[sel] = self._plan[sel]
        self._req[sel] = False
        self._seen_at[sel] = -1

    def _cells(self, x: npt.NDArray[np.int64],
               y: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.intp], ...]:
        """(row, window y, window x, grid y, grid x) of every cell on the grid of the windows
        around (x, y) [rows]."""
        n, side = x.shape[0], self.side
        h, w = self._highway.shape
        off = np.arange(side) - self.radius
        gy = np.broadcast_to(y[:, None, None] + off[None, :, None], (n, side, side))
        gx = np.broadcast_to(x[:, None, None] + off[None, None, :], (n, side, side))
        ri, wy, wx = np.nonzero((gy >= 0) & (gy < h) & (gx >= 0) & (gx < w))
        return ri, wy, wx, gy[ri, wy, wx], gx[ri, wy, wx]

    def _window(self, o: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.intp], ...]:
        """``_cells`` of the windows the observations ``o`` show."""
        return self._cells(np.rint(o[:, 0]).astype(np.int64), np.rint(o[:, 1]).astype(np.int64))

    def correct(self, obs: npt.ArrayLike, age: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Observations [rows, D] received ``age`` [rows] steps old -> predicted current ones.
        Call it on every observation received (a current one too): with ``memory`` the rule
        remembers the shelves each one shows."""
        o = np.array(obs, dtype=np.float32, copy=True)
        if o.shape != (self.rows, self.obs_size):
            raise ValueError(f"dead reckoning reads RWARE observations of sensor range "
                             f"{self.radius}: expected [{self.rows}, {self.obs_size}], got "
                             f"{list(o.shape)}")
        if self.memory:
            count = self.history.count
            when = count - np.minimum(np.asarray(age, dtype=np.int64).reshape(self.rows), count)
            newer = when >= self._seen_at
            self._seen_at = np.maximum(self._seen_at, when)
            ri, wy, wx, cy, cx = self._window(o)
            keep = newer[ri]
            ri, wy, wx, cy, cx = ri[keep], wy[keep], wx[keep], cy[keep], cx[keep]
            cell = o[:, RWARE_SELF:].reshape(self.rows, self.side, self.side, RWARE_CELL)
            self._shelf[ri, cy, cx] = cell[ri, wy, wx, 5] > 0.5
            self._req[ri, cy, cx] = cell[ri, wy, wx, 6] > 0.5
        d = self.history.unseen(age)
        busy = np.zeros(self.rows, dtype=bool)  # rows with an unseen action that is not a no-op
        for back in range(1, int(d.max(initial=0)) + 1):
            busy |= (d >= back) & (self.history.sent(back) != 0)
        rows = np.flatnonzero(busy)
        if rows.size == 0:
            return o
        o[rows] = self._predict(o[rows], d[rows], rows)
        return o

    def _predict(self, o: npt.NDArray[np.float32], d: npt.NDArray[np.int64],
                 hist_rows: npt.NDArray[np.intp]) -> npt.NDArray[np.float32]:
        n = o.shape[0]
        h, w = self._highway.shape
        side = self.side
        k = np.arange(n)
        x = np.rint(o[:, 0]).astype(np.int64)
        y = np.rint(o[:, 1]).astype(np.int64)
        load = o[:, 2] > 0.5
        head = np.argmax(o[:, 3:7], axis=1)
        # the floor as the robot knows it: what it remembers (the plan where it saw nothing),
        # overwritten by the window it sees
        shelf = (self._shelf if self.memory else self._plan)[hist_rows].copy()
        req = self._req[hist_rows].copy() if self.memory else np.zeros((n, h, w), dtype=bool)
        robot = np.zeros((n, h, w), dtype=np.int64)  # 0 none, 1 + heading
        win = o[:, RWARE_SELF:].reshape(n, side, side, RWARE_CELL)  # [row, wy, wx, feature]
        ri, wy, wx, cy, cx = self._window(o)
        cell = win[ri, wy, wx]
        shelf[ri, cy, cx] = cell[:, 5] > 0.5
        req[ri, cy, cx] = cell[:, 6] > 0.5
        robot[ri, cy, cx] = np.where(cell[:, 0] > 0.5, 1 + np.argmax(cell[:, 1:5], axis=1), 0)
        robot[k, y, x] = 0  # the robot itself: drawn from its predicted state
        creq = load & req[k, y, x]  # the carried shelf is requested
        dxy = np.asarray(_DXY, dtype=np.int64)
        for back in range(int(d.max()), 0, -1):  # oldest unseen action first
            use = d >= back
            a = np.where(use, self.history.sent(back)[hist_rows], 0)
            tx = np.clip(x + dxy[head, 0], 0, w - 1)  # rware clamps a move at the grid's edge
            ty = np.clip(y + dxy[head, 1], 0, h - 1)
            go = (a == FORWARD) & ((tx != x) | (ty != y)) & ~(load & shelf[k, ty, tx])
            moving = go & load  # the carried shelf goes along
            mk = k[moving]
            shelf[mk, y[moving], x[moving]] = False
            req[mk, y[moving], x[moving]] = False
            shelf[mk, ty[moving], tx[moving]] = True
            req[mk, ty[moving], tx[moving]] = creq[moving]
            x, y = np.where(go, tx, x), np.where(go, ty, y)
            head = np.where(a == LEFT, _TURN_LEFT[head],
                            np.where(a == RIGHT, _TURN_RIGHT[head], head))
            here = shelf[k, y, x]
            pick = (a == TOGGLE) & ~load & here
            drop = (a == TOGGLE) & load & ~self._highway[y, x]
            creq = np.where(pick, req[k, y, x], creq)
            load = (load | pick) & ~drop
            # a requested shelf on a goal is delivered: replaced in the queue, not requested
            delivered = use & load & creq & self._goal[y, x]
            creq &= ~delivered
            req[k[delivered], y[delivered], x[delivered]] = False
        return self._render(x, y, head=head, load=load, shelf=shelf, req=req, robot=robot)

    def _render(self, x: npt.NDArray[np.int64], y: npt.NDArray[np.int64], *,
                head: npt.NDArray[np.int64], load: npt.NDArray[np.bool_],
                shelf: npt.NDArray[np.bool_], req: npt.NDArray[np.bool_],
                robot: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        """rware's flattened observation of a robot at (x, y) with this heading and load, on a
        floor of these shelves, requests and other robots."""
        n, side = x.shape[0], self.side
        k = np.arange(n)
        out = np.zeros((n, self.obs_size), dtype=np.float32)
        out[:, 0], out[:, 1], out[:, 2] = x, y, load
        out[k, 3 + head] = 1.0
        out[:, 7] = self._highway[y, x]
        robot = robot.copy()
        robot[k, y, x] = 1 + head
        cells = np.broadcast_to(_EMPTY_CELL, (n, side, side, RWARE_CELL)).copy()
        ri, wy, wx, cy, cx = self._cells(x, y)
        rb = robot[ri, cy, cx]
        c = cells[ri, wy, wx]
        c[:, 0] = rb > 0
        c[:, 1:5] = 0.0
        c[np.arange(len(rb)), 1 + np.maximum(rb - 1, 0)] = 1.0
        c[:, 5] = shelf[ri, cy, cx]
        c[:, 6] = shelf[ri, cy, cx] & req[ri, cy, cx]
        cells[ri, wy, wx] = c
        out[:, RWARE_SELF:] = cells.reshape(n, -1)
        return out


def reckoner_for(env: str, rows: int = 1, horizon: int = HORIZON) -> Reckoner:
    """The rule for a named task (a MAIF grid or an RWARE warehouse); ValueError naming the
    tasks allowed for any other name."""
    from sdhn_sim.envs.maif_instances import MAIF_CONFIGS
    from sdhn_sim.envs.registry import RWARE_TASKS, make_env
    from sdhn_sim.envs.rware_batched import RwareBatchedEnv

    if env in MAIF_CONFIGS:
        return DeadReckoner(rows, MAIF_CONFIGS[env].size, horizon)
    if env in RWARE_TASKS:
        w = make_env(env, num_envs=1)
        assert isinstance(w, RwareBatchedEnv)
        return RwareDeadReckoner(rows, w.layout, w.sensor_range, horizon)
    raise ValueError(f"dead reckoning: env {env!r} unknown; allowed: one of "
                     f"{', '.join([*MAIF_CONFIGS, *RWARE_TASKS])}")
