"""RWARE in NumPy, B warehouses stepped at once: ``rware`` 2.0.0's rules, step for step.

The real ``rware`` package (``rware_env.RwareEnv``) stays the reference; this module re-expresses
its ``Warehouse.step``/``reset`` on arrays so that a training batch of B warehouses costs a few
dozen NumPy calls per step instead of B Python steps. ``test/envs/test_rware_batched.py`` holds
the two equal (observations, rewards, dones, robot poses, carried shelves, request queue) over
random and scripted rollouts on every layout the project uses.

Rules reproduced (from rware's ``warehouse.py``, the spec):

- **Layout**: shelf columns of 2, column height 8, highways every 3rd column and every
  ``column_height + 1``-th row, the delivery row at the bottom with two goals in its middle, a
  queue corridor above the goals. Shelves stand on the non-highway cells, numbered row-major.
- **Reset**: from the env's own generator, exactly rware's draws in rware's order: robot cells
  (``choice(H*W, N, replace=False)``, any cell), robot directions (``choice(4, N)``), the request
  queue (``choice(S, Q, replace=False)``). Seeding is gymnasium's (``default_rng(seed)``), so a
  batched env and a real one seeded alike draw the same warehouse and the same requests.
- **Moves**: FORWARD targets the next cell (clamped at the border). A loaded robot whose target
  holds a shelf that is not carried by a robot standing there is cancelled. rware then builds the
  graph cell -> target cell (one edge per robot) and, per weakly connected component: a cycle of
  length 2 (a swap) commits nobody; any other cycle commits the robots on it; an acyclic component
  commits the robots on networkx's ``dag_longest_path`` (the longest chain of robots queued into
  the free cell). Uncommitted robots stay. Here the graph is a functional graph on robots (each
  robot points at the robot on its target cell, at itself when it stays, or at "free"), resolved
  with a few vectorised pointer walks. The one thing that depends on networkx internals is which
  of two equally long chains ``dag_longest_path`` keeps; an env where such a tie occurs is
  resolved by networkx itself, with rware's own construction (rare: two robots entering the
  same free cell at once).
- **Turns, loads**: LEFT/RIGHT turn in place; TOGGLE_LOAD picks up the shelf at the robot's cell,
  or puts the carried shelf down if the cell is not a highway.
- **Deliveries**: for each goal in order, a requested shelf on it is replaced in the queue by
  ``choice`` over the shelves not requested (in shelf order), and the robot on it gets +1
  (individual reward, the registered tasks' reward).
- **Observations**: rware's flattened vector: x, y, carrying, direction one-hot, on highway; then
  per cell of the (2r+1)^2 window (row-major, zero padding outside the map): robot present, its
  direction one-hot ([1, 0, 0, 0] when no robot), shelf present, shelf requested.
- **Episode end**: after ``max_steps`` steps (rware says terminated; reported here, as by the
  adapter, as a truncation), then auto-reset from the env's generator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .api import EpisodeStats, FloatArray, StepResult
from .rware_env import (
    NUM_ACTIONS,
    RWARE_DIFFICULTIES,
    action_range_error,
    check_batch_args,
    checked_actions,
    first_reset_seeds,
    rware_env_id,
)

# rware's registered sizes: (shelf rows, shelf columns); column height 8 for all of them
RWARE_LAYOUTS = {"tiny": (1, 3), "small": (2, 3), "medium": (2, 5), "large": (3, 5)}
DIFFICULTY_FACTOR = {"easy": 2.0, "normal": 1.0, "hard": 0.5}  # request queue = N x factor
assert set(DIFFICULTY_FACTOR) == set(RWARE_DIFFICULTIES)  # the adapter's names, same meaning
COLUMN_HEIGHT = 8
NOOP, FORWARD, LEFT, RIGHT, TOGGLE = range(NUM_ACTIONS)
# rware Direction values: UP 0, DOWN 1, LEFT 2, RIGHT 3, as (dx, dy)
_DXY = ((0, -1), (0, 1), (-1, 0), (1, 0))
# rware turns through [UP, RIGHT, DOWN, LEFT]: RIGHT is the next, LEFT the previous
_TURN_RIGHT = np.array([3, 2, 0, 1], dtype=np.int64)
_TURN_LEFT = np.array([2, 3, 1, 0], dtype=np.int64)


@dataclass(frozen=True)
class Layout:
    """A warehouse floor: its size, highways, goals and the shelves' home cells."""

    height: int
    width: int
    highway: npt.NDArray[np.bool_]  # [H, W]
    goals: tuple[tuple[int, int], ...]  # (x, y), rware's order
    shelf_home: npt.NDArray[np.int64]  # [S] row-major cell index y * W + x

    @property
    def num_shelves(self) -> int:
        return int(self.shelf_home.shape[0])


def make_layout(shelf_rows: int, shelf_columns: int, column_height: int = COLUMN_HEIGHT) -> Layout:
    """rware's ``_make_layout_from_params``."""
    if shelf_columns % 2 != 1:
        raise ValueError(f"shelf_columns must be odd (rware), got {shelf_columns}")
    h = (column_height + 1) * shelf_rows + 2
    w = 3 * shelf_columns + 1
    y, x = np.indices((h, w))
    highway = (
        (x % 3 == 0)
        | (y % (column_height + 1) == 0)
        | (y == h - 1)
        | ((y > h - (column_height + 3)) & ((x == w // 2 - 1) | (x == w // 2)))
    )
    goals = ((w // 2 - 1, h - 1), (w // 2, h - 1))
    return Layout(h, w, highway, goals, np.flatnonzero(~highway.reshape(-1)).astype(np.int64))


class RwareBatchedEnv:
    """B RWARE warehouses in NumPy (implements ``BatchedEnv``); equal to ``RwareEnv`` seeded
    alike: copy ``b`` of a batch seeded ``s`` is first reset with seed ``s + b`` and its later
    episodes continue that generator."""

    num_actions = NUM_ACTIONS

    def __init__(
        self,
        num_robots: int,
        num_envs: int = 1,
        seed: int = 0,
        *,
        size: str = "small",
        difficulty: str = "normal",
        max_steps: int = 500,
        sensor_range: int = 1,
        name: str | None = None,
    ) -> None:
        self.env_id = rware_env_id(num_robots, size, difficulty)  # validates size/difficulty/N
        check_batch_args(num_envs, max_steps, seed)
        if int(sensor_range) < 1:
            raise ValueError(f"sensor_range must be >= 1, got {sensor_range}")
        self.name = name or self.env_id
        self.num_envs = nb = int(num_envs)
        self.num_robots = n = int(num_robots)
        self.max_steps = int(max_steps)
        self.sensor_range = r = int(sensor_range)
        self.layout = lay = make_layout(*RWARE_LAYOUTS[size])
        self.queue_size = int(n * DIFFICULTY_FACTOR[difficulty])
        self.obs_size = 8 + (2 * r + 1) ** 2 * 7
        self.state_size = n * self.obs_size
        self._pending_seed = first_reset_seeds(seed, nb)
        self._rngs: list[np.random.Generator | None] = [None] * nb
        self._build_tables()
        s = lay.num_shelves
        # state: robots by padded cell index (see _build_tables), shelves likewise
        self.cell = np.zeros((nb, n), dtype=np.int64)
        self.dir = np.zeros((nb, n), dtype=np.int64)
        self.carry = np.full((nb, n), -1, dtype=np.int64)  # shelf index, -1 = none
        self.shelf_cell = np.zeros((nb, s), dtype=np.int64)
        self.queue = np.zeros((nb, self.queue_size), dtype=np.int64)
        self.requested = np.zeros((nb, s), dtype=bool)
        self._t = np.zeros(nb, dtype=np.int64)
        self._ret = np.zeros(nb, dtype=np.float64)
        self._deliveries = np.zeros(nb, dtype=np.int64)
        # flat [B * P] grids over the padded map: robot index / shelf index at each cell, -1
        self._base = (np.arange(nb, dtype=np.int64) * self._p)[:, None]
        self._robot_at = np.full(nb * self._p, -1, dtype=np.int64)
        self._shelf_at = np.full(nb * self._p, -1, dtype=np.int64)
        self._arange_n = np.arange(n, dtype=np.int64)
        self._arange_s = np.arange(s, dtype=np.int64)
        self._flat_n = (np.arange(nb, dtype=np.int64) * n)[:, None]
        self._started = False
        self.ties_resolved_by_networkx = 0  # envs-steps whose move conflicts needed networkx
        self.robot_rewards: FloatArray = np.zeros((nb, n), np.float32)

    # ---------------------------------------------------------------- tables
    def _build_tables(self) -> None:
        """Precomputed per-cell tables over the map padded by the sensor range r (cell index
        (y + r) * (W + 2r) + x + r): the forward neighbour (rware clamps at the border), the
        self part of the observation, the observation window offsets, the highway flag."""
        lay, r = self.layout, self.sensor_range
        h, w = lay.height, lay.width
        pw = w + 2 * r
        self._pw = pw
        self._p = (h + 2 * r) * pw
        y, x = np.indices((h, w))
        inner = ((y + r) * pw + x + r).reshape(-1)  # padded index of each map cell, row-major
        self._inner = inner
        p = self._p
        self._xy = np.zeros((p, 2), dtype=np.int64)
        self._xy[inner, 0] = x.reshape(-1)
        self._xy[inner, 1] = y.reshape(-1)
        nbr = np.zeros((p, 4), dtype=np.int64)
        for d, (dx, dy) in enumerate(_DXY):
            tx = np.clip(x + dx, 0, w - 1)
            ty = np.clip(y + dy, 0, h - 1)
            nbr[inner, d] = ((ty + r) * pw + tx + r).reshape(-1)
        self._nbr = nbr
        hw = np.zeros(p, dtype=bool)
        hw[inner] = lay.highway.reshape(-1)
        self._highway = hw
        # self features by (cell, dir, loaded): x, y, loaded, dir one-hot, on highway
        self_t = np.zeros((p, 4, 2, 8), dtype=np.float32)
        self_t[:, :, :, 0] = self._xy[:, 0, None, None]
        self_t[:, :, :, 1] = self._xy[:, 1, None, None]
        self_t[:, :, 1, 2] = 1.0
        for d in range(4):
            self_t[:, d, :, 3 + d] = 1.0
        self_t[:, :, :, 7] = hw[:, None, None]
        self._self_t = self_t.reshape(p * 8, 8)
        offsets = np.indices((2 * r + 1, 2 * r + 1)) - r  # (dy, dx)
        self._window = (offsets[0] * pw + offsets[1]).reshape(-1)  # row-major, as rware reads
        # sensor features by code robot_code * 3 + shelf_code: robot_code 0 none, 1 + dir;
        # shelf_code 0 none, 1 shelf, 2 requested shelf
        sensor_t = np.zeros((15, 7), dtype=np.float32)
        for rc in range(5):
            for sc in range(3):
                row = sensor_t[rc * 3 + sc]
                if rc == 0:
                    row[1] = 1.0  # rware writes direction UP for an empty cell
                else:
                    row[0] = 1.0
                    row[1 + rc - 1] = 1.0
                row[5] = float(sc > 0)
                row[6] = float(sc == 2)
        self._sensor_t = sensor_t
        self._goal_cells = np.array([(gy + r) * pw + gx + r for gx, gy in lay.goals],
                                    dtype=np.int64)
        self._shelf_home = inner[lay.shelf_home]

    # ---------------------------------------------------------------- reset
    def _reset_one(self, b: int) -> None:
        seed = self._pending_seed[b]
        self._pending_seed[b] = None
        if seed is not None or self._rngs[b] is None:
            self._rngs[b] = np.random.default_rng(seed)  # gymnasium's seeding.np_random
        rng = self._rngs[b]
        assert rng is not None
        lay, n = self.layout, self.num_robots
        locs = rng.choice(np.arange(lay.height * lay.width), size=n, replace=False)
        dirs = rng.choice(4, size=n)
        queue = rng.choice(lay.num_shelves, size=self.queue_size, replace=False)
        self.cell[b] = self._inner[locs]
        self.dir[b] = dirs
        self.carry[b] = -1
        self.shelf_cell[b] = self._shelf_home
        self.queue[b] = queue
        self.requested[b] = False
        self.requested[b, queue] = True
        self._t[b] = 0
        self._ret[b] = 0.0
        self._deliveries[b] = 0

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        if seed is not None:
            self._pending_seed = first_reset_seeds(seed, self.num_envs)
        for b in range(self.num_envs):
            self._reset_one(b)
        self._started = True
        self._fill_grids()
        obs = self._observe()
        return obs, obs.reshape(self.num_envs, -1)

    # ---------------------------------------------------------------- step
    def _fill_grids(self) -> None:
        self._robot_at.fill(-1)
        self._robot_at[(self._base + self.cell).reshape(-1)] = np.broadcast_to(
            self._arange_n, self.cell.shape).reshape(-1)
        self._shelf_at.fill(-1)
        self._shelf_at[(self._base + self.shelf_cell).reshape(-1)] = np.broadcast_to(
            self._arange_s, self.shelf_cell.shape).reshape(-1)

    def step(self, actions: npt.ArrayLike) -> StepResult:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        nb, n = self.num_envs, self.num_robots
        a = checked_actions(actions, nb, n)
        if a.min() < 0 or a.max() >= NUM_ACTIONS:
            raise action_range_error(a)
        a = a.astype(np.int64)
        cell, loaded = self.cell, self.carry >= 0
        forward = a == FORWARD
        target = np.where(forward, self._nbr[cell, self.dir], cell)
        gtarget = self._base + target
        occupant = self._robot_at[gtarget]  # robot index on the target cell, -1 none
        if forward.any():
            # a loaded robot cannot enter a cell with a shelf, unless a loaded robot stands there
            occ_loaded = np.take_along_axis(loaded, np.maximum(occupant, 0), axis=1) & (
                occupant >= 0)
            cancel = (forward & loaded & (target != cell) & (self._shelf_at[gtarget] >= 0)
                      & ~occ_loaded)
            target = np.where(cancel, cell, target)
            occupant = np.where(cancel, self._arange_n, occupant)
            moving = target != cell
            if moving.any():
                move = self._resolve(a, cell, target, occupant, moving)
                self.cell = cell = np.where(move, target, cell)
                carried = loaded & move
                if carried.any():
                    bi, ri = np.nonzero(carried)
                    self.shelf_cell[bi, self.carry[bi, ri]] = cell[bi, ri]
        turn_l, turn_r = a == LEFT, a == RIGHT
        if turn_l.any() or turn_r.any():
            self.dir = np.where(turn_l, _TURN_LEFT[self.dir],
                                np.where(turn_r, _TURN_RIGHT[self.dir], self.dir))
        toggle = a == TOGGLE
        if toggle.any():
            # picking up reads the grid of the step's start (rware recalculates it after)
            under = self._shelf_at[self._base + cell]
            pick = toggle & ~loaded & (under >= 0)
            drop = toggle & loaded & ~self._highway[cell]
            self.carry = np.where(pick, under, np.where(drop, -1, self.carry))
        self._fill_grids()
        rewards = self._deliver()
        self._t += 1
        obs = self._observe()
        team = rewards.sum(axis=1)
        self._ret += team
        self._deliveries += np.rint(team).astype(np.int64)
        self.robot_rewards = rewards
        done = self._t >= self.max_steps
        final_obs = obs
        episodes: list[EpisodeStats] = []
        if done.any():
            final_obs = obs.copy()
            finished = np.flatnonzero(done)
            for b in finished.tolist():
                episodes.append(EpisodeStats(
                    env_index=b, episode_return=float(self._ret[b]), length=int(self._t[b]),
                    makespan=None, completed=False, collisions=0, formation_error=0.0,
                    deliveries=int(self._deliveries[b])))
                self._reset_one(b)
            self._fill_grids()
            obs = self._observe()
        return StepResult(
            obs=obs,
            state=obs.reshape(nb, -1),
            reward=team.astype(np.float32),
            terminated=np.zeros(nb, dtype=bool),
            truncated=done,
            final_obs=final_obs,
            final_state=final_obs.reshape(nb, -1),
            episodes=episodes,
        )

    def _resolve(self, a: npt.NDArray[np.int64], cell: npt.NDArray[np.int64],
                 target: npt.NDArray[np.int64], occupant: npt.NDArray[np.int64],
                 moving: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
        """Which moving robots rware commits ([B, N]). Robots are nodes of a functional graph
        over flat indices b * N + i, with one extra node F (= B * N, "a free cell") that points
        at itself: a moving robot points at the robot on its target cell or at F; a robot that
        stays points at itself."""
        nb, n = self.num_envs, self.num_robots
        free = nb * n
        own = (self._flat_n + self._arange_n).reshape(-1)
        nxt = np.empty(free + 1, dtype=np.int64)
        nxt[:free] = np.where(moving & (occupant >= 0), self._flat_n + occupant,
                              np.where(moving, free, own.reshape(nb, n))).reshape(-1)
        nxt[free] = free
        # walk every chain: where it ends (F or a cycle), and the length of the cycle a robot
        # is on (0 = not on one)
        cyc_len = np.zeros(free, dtype=np.int64)
        cur = nxt[:free]
        for k in range(1, n + 1):
            back = (cur == own) & (cyc_len == 0)
            cyc_len[back] = k
            if k < n:
                cur = nxt[cur]
        on_cycle = cyc_len > 0
        reaches_free = cur == free  # after n steps a chain ending at F is there (F absorbs)
        mv = moving.reshape(-1)
        commit = mv & on_cycle & (cyc_len != 2)
        acyclic = mv & reaches_free
        if acyclic.any():
            chosen, tied = self._longest_chains(acyclic, target.reshape(-1), nxt, free)
            ok = chosen.copy()
            cur = nxt[:free]
            chosen_f = np.append(chosen, True)
            for _ in range(n):
                ok &= chosen_f[cur]
                cur = nxt[cur]
            commit |= acyclic & ok
            if tied.any():
                out = commit.reshape(nb, n)
                tied_bn = tied.reshape(nb, n)
                for b in np.flatnonzero(tied_bn.any(axis=1)).tolist():
                    cells = {(int(x), int(y)) for x, y in self._xy[target[b, tied_bn[b]]]}
                    in_comp, nx_commit = _networkx_commit(self._xy[cell[b]],
                                                          self._xy[target[b]], cells)
                    out[b] = np.where(in_comp, nx_commit, out[b])
                    self.ties_resolved_by_networkx += 1
                return out
        return commit.reshape(nb, n)

    def _longest_chains(self, acyclic: npt.NDArray[np.bool_], target: npt.NDArray[np.int64],
                        nxt: npt.NDArray[np.int64], free: int,
                        ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """For robots in acyclic components: whether each is the deepest robot queued into its
        target cell (``dag_longest_path`` follows the deepest predecessor), and whether it is
        one of two or more equally deep ones (networkx's order decides there)."""
        nb, n = self.num_envs, self.num_robots
        idx = np.flatnonzero(acyclic)
        env_of = idx // n
        gt = env_of * self._p + target[idx]  # the target cell as a node, flat over the batch
        depth = np.zeros(idx.size, dtype=np.int64)  # longest chain of robots behind each
        # a robot's own cell as the node its followers point at
        own_cell = (env_of * self._p + self.cell.reshape(-1)[idx])
        best = np.full(nb * self._p, -1, dtype=np.int64)
        for _ in range(n):
            best.fill(-1)
            np.maximum.at(best, gt, depth)
            new = best[own_cell] + 1
            if np.array_equal(new, depth):
                break
            depth = new
        best.fill(-1)
        np.maximum.at(best, gt, depth)
        top = depth == best[gt]
        count = np.zeros(nb * self._p, dtype=np.int64)
        np.add.at(count, gt[top], 1)
        tie = top & (count[gt] > 1)
        chosen = np.zeros(free, dtype=bool)
        chosen[idx[top]] = True
        tied = np.zeros(free, dtype=bool)
        tied[idx[tie]] = True
        return chosen, tied

    def _deliver(self) -> FloatArray:
        """rware's delivery loop over the goals, for the envs where a requested shelf stands on
        a goal (a new request may fall on the shelf on the other goal: checked in order)."""
        nb, n = self.num_envs, self.num_robots
        rewards = np.zeros((nb, n), dtype=np.float32)
        on_goal = self._shelf_at[self._base + self._goal_cells]  # [B, 2]
        has = on_goal >= 0
        if not has.any():
            return rewards
        req = np.take_along_axis(self.requested, np.maximum(on_goal, 0), axis=1) & has
        for b in np.flatnonzero(req.any(axis=1)).tolist():
            rng = self._rngs[b]
            assert rng is not None
            for g, gc in enumerate(self._goal_cells.tolist()):
                s = int(on_goal[b, g])
                if s < 0 or not self.requested[b, s]:
                    continue
                candidates = np.flatnonzero(~self.requested[b])
                new = int(rng.choice(candidates))
                slot = int(np.flatnonzero(self.queue[b] == s)[0])
                self.queue[b, slot] = new
                self.requested[b, s] = False
                self.requested[b, new] = True
                rewards[b, self._robot_at[b * self._p + gc]] += 1.0
        return rewards

    def _observe(self) -> FloatArray:
        nb, n = self.num_envs, self.num_robots
        gcell = self._base + self.cell
        robot_code = np.zeros(nb * self._p, dtype=np.int64)
        robot_code[gcell.reshape(-1)] = self.dir.reshape(-1) + 1
        shelf_code = np.zeros(nb * self._p, dtype=np.int64)
        shelf_code[(self._base + self.shelf_cell).reshape(-1)] = (
            self.requested.reshape(-1).astype(np.int64) + 1)
        win = gcell[:, :, None] + self._window  # [B, N, cells]
        sensors = self._sensor_t[robot_code[win] * 3 + shelf_code[win]]
        own = self._self_t[self.cell * 8 + self.dir * 2 + (self.carry >= 0)]
        return np.concatenate([own, sensors.reshape(nb, n, -1)], axis=2)

    # ---------------------------------------------------------------- views
    @property
    def positions(self) -> npt.NDArray[np.int64]:
        """[B, N, 2] (x, y) of every robot."""
        return self._xy[self.cell]

    @property
    def request_queue(self) -> npt.NDArray[np.int64]:
        """[B, Q] requested shelf indices (0-based; rware's shelf id - 1), rware's slot order."""
        return self.queue.copy()

    @property
    def shelf_positions(self) -> npt.NDArray[np.int64]:
        """[B, S, 2] (x, y) of every shelf (0-based index = rware's shelf id - 1)."""
        return self._xy[self.shelf_cell]

    def close(self) -> None:
        pass


def _networkx_commit(start: npt.NDArray[np.int64], target: npt.NDArray[np.int64],
                     tied_cells: set[tuple[int, int]],
                     ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """rware's networkx resolution of the components holding ``tied_cells``, built as rware
    builds it (the whole graph: edges (x, y) -> target (x, y) added in robot order, since the
    order networkx iterates a component in depends on it), per component a cycle (not a swap)
    or else ``dag_longest_path``. Returns (robot in such a component, robot committed)."""
    import networkx as nx

    graph: Any = nx.DiGraph()
    pos = [(int(x), int(y)) for x, y in start]
    for p, (tx, ty) in zip(pos, target.tolist(), strict=True):
        graph.add_edge(p, (int(tx), int(ty)))
    robot_at = {p: i for i, p in enumerate(pos)}
    in_comp = np.zeros(len(pos), dtype=bool)
    commit = np.zeros(len(pos), dtype=bool)
    for nodes in nx.weakly_connected_components(graph):
        if tied_cells.isdisjoint(nodes):
            continue
        for p in nodes:
            if p in robot_at:
                in_comp[robot_at[p]] = True
        comp = graph.subgraph(nodes).copy()
        try:
            cycle = nx.algorithms.find_cycle(comp)
            if len(cycle) == 2:
                continue
            on_path = [edge[0] for edge in cycle]
        except nx.NetworkXNoCycle:
            on_path = nx.algorithms.dag_longest_path(comp)
        for p in on_path:
            if p in robot_at:
                commit[robot_at[p]] = True
    return in_comp, commit
