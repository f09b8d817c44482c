"""MAIF (Moving Agents In Formation), batched: B environments x N robots per NumPy call.

The rules as implemented are described in ``docs/maif.md``. Axis convention: see
``maif_instances`` (x = column to the right, y = row downwards, ``up`` = y - 1). Actions: 0 stay,
1 up, 2 down, 3 left, 4 right.

Internally every environment has a padded ``(size + 6) x (size + 6)`` int8 canvas (a border of
3 = the observation radius): 0 free, 1 obstacle or outside, 2 robot. Robots are tracked by their
flat index into the batch of canvases, so moves, the obstacle test, conflict detection and the
7x7 observation windows are all gathers/scatters on one flat array; there is no per-robot Python
loop in ``step`` (the conflict fix-point iterates over conflict *rounds*, vectorised over robots).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .api import BoolArray, EpisodeStats, FloatArray, IntArray, StepResult
from .maif_instances import MaifConfig, MaifInstances, ProceduralInstances, load_instances
from .render import render_grid

NUM_ACTIONS = 5
RADIUS = 3
WINDOW = 2 * RADIUS + 1
COORD_FEATURES = 8
OBS_SIZE = COORD_FEATURES + WINDOW * WINDOW  # 57
MAX_STEPS = 500
INSTANCE_ORDERS = ("random", "round_robin")
# (dx, dy) per action: stay, up (y-1), down (y+1), left (x-1), right (x+1)
ACTION_DELTAS = np.array([[0, 0], [0, -1], [0, 1], [-1, 0], [1, 0]], dtype=np.int64)


@dataclass(frozen=True)
class MaifRewards:
    """Reward terms of the spec (per robot; the team reward is their sum). The defaults are the
    ``reference`` terms (the benchmark's); see ``MAIF_REWARDS`` for the named sets."""

    move: float = -0.075
    stay_off_goal: float = -0.075
    stay_on_goal: float = 1.0
    collision: float = -0.5
    progress: float = 0.1  # the L1 distance to the own goal shrank this step
    formation_scale: float = 0.001
    completion: float = 3.0
    progress_away: float = 0.0  # the L1 distance grew this step (corrected: -0.1)
    name: str = "reference"


# ``reference``: the benchmark's terms (oscillating earns more than waiting; standing on one's
# goal pays +1 per step, so completing ends an income). ``corrected`` (the training default):
# potential-based progress (+0.1 closer, -0.1 farther) and no stay-on-goal income. See
# docs/maif_rewards.md.
MAIF_REWARDS: dict[str, MaifRewards] = {
    "reference": MaifRewards(),
    "corrected": MaifRewards(stay_on_goal=0.0, progress_away=-0.1, name="corrected"),
}
DEFAULT_REWARD = "corrected"


@dataclass(frozen=True)
class MaifWorld:
    """A copy of one environment's world, for the simulator node, viewers and rendering."""

    positions: IntArray  # [N, 2] (x, y)
    goals: IntArray  # [N, 2] (x, y)
    obstacles: BoolArray  # [size, size], indexed [y, x]
    instance_id: int
    step: int

    def render_rgb(self, cell_px: int = 8) -> npt.NDArray[np.uint8]:
        return render_grid(self.obstacles, self.positions, self.goals, cell_px)


def resolve_moves(
    cur: IntArray, moves: IntArray, blocked: BoolArray, occupant: IntArray
) -> tuple[IntArray, BoolArray]:
    """Resolve simultaneous moves on flat cell ids; returns (new cells, collided).

    ``cur``: current flat cell of each robot (unique); ``moves``: flat offset of its requested move
    (0 = stay); ``blocked``: the requested target is an obstacle or outside the grid;
    ``occupant``: flat array mapping a cell to the index (into ``cur``) of the robot on it, or -1.
    Robot order in ``cur`` is the priority order (lower index wins a vertex conflict).
    """
    moving = (moves != 0) & ~blocked
    collided = (moves != 0) & blocked
    tgt = np.where(moving, cur + moves, cur)
    # Round 1, all rules at once. Vertex: per target cell a stayer sorts first, then movers by
    # index; everyone after the first loses. Swap: i moves onto j's cell while j moves onto i's.
    order = np.argsort(tgt * 2 + moving, kind="stable")
    cells = tgt[order]
    dup = np.zeros(cur.shape[0], dtype=bool)
    dup[1:] = cells[1:] == cells[:-1]
    j = occupant[tgt]
    lose = moving & (j >= 0) & (tgt[j] == cur)
    lose[order[dup]] = True
    # Later rounds. Movers' targets never change (a loser's target becomes its own cell), so no
    # new mover/mover vertex or swap conflict can appear: only a mover heading for the cell of a
    # robot that has just been stopped. Iterate that until nothing changes.
    while lose.any():
        tgt[lose] = cur[lose]
        moving &= ~lose
        collided |= lose
        j = occupant[tgt]
        lose = moving & ~moving[j]  # j >= 0 for every mover whose target is occupied
        lose &= j >= 0
    return tgt, collided


class MaifEnv:
    """B MAIF environments x N robots (implements ``BatchedEnv``).

    ``config`` is a configuration name, a ``MaifConfig`` (its instance set is loaded or
    generated) or a ready ``MaifInstances`` (e.g. a hand-built scenario in a test).
    ``reward`` names the reward terms (``MAIF_REWARDS``: "corrected", the default, or
    "reference"); ``rewards`` gives custom terms instead. ``reward_name`` says which is used.

    Env ``b`` of a batch seeded ``s`` behaves exactly like a single environment seeded ``s + b``
    (each draws its instances with its own generator) in ``"random"`` order. In ``"round_robin"``
    order env ``b`` plays ``ids[(b + k * B) % len(ids)]`` in its k-th episode, so a batch covers
    every instance once in ``ceil(len(ids) / B)`` episodes per env.
    """

    num_actions = NUM_ACTIONS
    obs_size = OBS_SIZE

    def __init__(
        self,
        config: MaifConfig | MaifInstances | ProceduralInstances | str,
        num_envs: int = 1,
        seed: int = 0,
        *,
        max_steps: int = MAX_STEPS,
        instance_ids: Sequence[int] | None = None,
        instance_order: str = "random",
        rewards: MaifRewards | None = None,
        name: str | None = None,
        reward: str = DEFAULT_REWARD,
    ) -> None:
        inst = (config if isinstance(config, MaifInstances | ProceduralInstances)
                else load_instances(config))
        cfg = inst.config
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if int(max_steps) < 1:
            raise ValueError(f"max_steps must be an int >= 1, got {max_steps!r}")
        if instance_order not in INSTANCE_ORDERS:
            raise ValueError(
                f"instance_order must be one of {list(INSTANCE_ORDERS)}, got {instance_order!r}"
            )
        total = inst.num_instances
        ids = np.arange(total) if instance_ids is None else np.asarray(instance_ids)
        if (
            ids.ndim != 1
            or ids.size == 0
            or ids.dtype.kind not in "iu"
            or ids.min() < 0
            or ids.max() >= total
        ):
            raise ValueError(
                f"instance_ids must be a non-empty list of ints in [0, {total}), "
                f"got {instance_ids!r}"
            )
        ids = ids.astype(np.int64)
        if rewards is None and reward not in MAIF_REWARDS:
            raise ValueError(f"reward must be one of {list(MAIF_REWARDS)}, got {reward!r}")
        self.name = name or cfg.name
        self.config = cfg
        self.instances = inst
        self.num_envs = b = int(num_envs)
        self.num_robots = n = cfg.num_robots
        self.state_size = n * OBS_SIZE
        self.max_steps = int(max_steps)
        self.instance_ids = ids
        self.instance_order = instance_order
        self.size = s = cfg.size
        self._p = p = s + 2 * RADIUS
        self._inv = np.float32(1.0 / (s - 1))

        self._canvas = np.ones((b, p, p), dtype=np.int8)
        self._flat = self._canvas.reshape(-1)  # view
        self._occ = np.full(b * p * p, -1, dtype=np.int64)
        self._act_off = ACTION_DELTAS[:, 0] + ACTION_DELTAS[:, 1] * p
        dy, dx = np.divmod(np.arange(WINDOW * WINDOW), WINDOW)
        self._win_off = (dy - RADIUS) * p + (dx - RADIUS)
        self._robot_ids = np.arange(b * n, dtype=np.int64)
        self._env_base = (np.arange(b, dtype=np.int64) * p * p)[:, None]

        # positions and goals per axis ([B, N] contiguous: reductions over robots stay cheap)
        self._x = np.zeros((b, n), dtype=np.int64)
        self._y = np.zeros((b, n), dtype=np.int64)
        self._cell = np.zeros((b, n), dtype=np.int64)
        self._gx = np.zeros((b, n), dtype=np.int64)
        self._gy = np.zeros((b, n), dtype=np.int64)
        self._gox = np.zeros((b, n), dtype=np.float64)  # goal offset from the goal centroid
        self._goy = np.zeros((b, n), dtype=np.float64)
        self._idx_buf = np.empty((b, n, WINDOW * WINDOW), dtype=np.int64)
        self._win_buf = np.empty((b, n, WINDOW * WINDOW), dtype=np.int8)
        self.rewards = rw = rewards or MAIF_REWARDS[reward]
        self.reward_name = rw.name
        # base reward by (stay, stay-on-goal): index = stay + (stay & on_goal)
        self._base_reward = np.array([rw.move, rw.stay_off_goal, rw.stay_on_goal])
        self._goal_feat = np.zeros((b, n, 4), dtype=np.float32)
        self._dist = np.zeros((b, n), dtype=np.int64)
        self._instance = np.zeros(b, dtype=np.int64)
        self._t = np.zeros(b, dtype=np.int64)
        self._ret = np.zeros(b, dtype=np.float64)
        self._coll = np.zeros(b, dtype=np.int64)
        self._ferr = np.zeros(b, dtype=np.float64)
        self._episode = np.zeros(b, dtype=np.int64)
        self._seed = int(seed)
        self._rngs: list[np.random.Generator] = []
        self._started = False
        # Per-robot detail of the last step (for IPPO-style learners, the simulator node, logs).
        self.robot_rewards: FloatArray = np.zeros((b, n), dtype=np.float32)
        self.robot_collisions: BoolArray = np.zeros((b, n), dtype=bool)
        # World of each env that finished at the last step, taken before its auto-reset.
        self.final_worlds: dict[int, MaifWorld] = {}
        self._reseed(self._seed)

    # ------------------------------------------------------------------ episodes
    def _reseed(self, seed: int) -> None:
        if int(seed) < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self._seed = int(seed)
        self._rngs = [np.random.default_rng(self._seed + k) for k in range(self.num_envs)]
        self._episode[:] = 0

    def _next_instance(self, b: int) -> int:
        ids = self.instance_ids
        if self.instance_order == "random":
            k = int(ids[self._rngs[b].integers(ids.size)])
        else:
            k = int(ids[(b + int(self._episode[b]) * self.num_envs) % ids.size])
        self._episode[b] += 1
        return k

    def _reset_env(self, b: int) -> None:
        k = self._next_instance(b)
        obstacles, starts, goals = self.instances.instance(k)
        p, s = self._p, self.size
        self._occ[self._cell[b]] = -1
        # the map padded by RADIUS cells of wall (built here: a procedural set has no map list)
        self._canvas[b] = 1
        self._canvas[b, RADIUS : RADIUS + s, RADIUS : RADIUS + s] = obstacles
        cells = b * p * p + (starts[:, 1] + RADIUS) * p + (starts[:, 0] + RADIUS)
        self._flat[cells] = 2
        self._occ[cells] = self._robot_ids[b * self.num_robots : (b + 1) * self.num_robots]
        self._cell[b] = cells
        self._x[b], self._y[b] = starts[:, 0], starts[:, 1]
        self._gx[b], self._gy[b] = goals[:, 0], goals[:, 1]
        goal_off = goals - goals.mean(axis=0)
        self._gox[b], self._goy[b] = goal_off[:, 0], goal_off[:, 1]
        inv = 1.0 / (s - 1)
        self._goal_feat[b, :, 0:2] = goals * inv
        self._goal_feat[b, :, 2:4] = goals.mean(axis=0) * inv
        self._dist[b] = np.abs(starts - goals).sum(axis=1)
        self._instance[b] = k
        self._t[b] = 0
        self._ret[b] = 0.0
        self._coll[b] = 0
        self._ferr[b] = 0.0

    def reset(self, seed: int | None = None) -> tuple[FloatArray, FloatArray]:
        """New episode everywhere. With a seed, restart every env's instance stream from it."""
        if seed is not None:
            self._reseed(seed)
        if not self._started:
            self._occ[:] = -1
            self._started = True
        for b in range(self.num_envs):
            self._reset_env(b)
        self.final_worlds = {}
        obs = self._observe()
        return obs, obs.reshape(self.num_envs, -1)

    # ------------------------------------------------------------------ stepping
    def _observe(self) -> FloatArray:
        b, n, inv = self.num_envs, self.num_robots, self._inv
        obs = np.empty((b, n, OBS_SIZE), dtype=np.float32)
        np.multiply(self._x, inv, out=obs[:, :, 0])
        np.multiply(self._y, inv, out=obs[:, :, 1])
        obs[:, :, 2] = (self._x.sum(axis=1) * (inv / n))[:, None]
        obs[:, :, 3] = (self._y.sum(axis=1) * (inv / n))[:, None]
        obs[:, :, 4:8] = self._goal_feat
        np.add(self._cell[:, :, None], self._win_off, out=self._idx_buf)
        np.take(self._flat, self._idx_buf, out=self._win_buf)
        obs[:, :, COORD_FEATURES:] = self._win_buf
        obs[:, :, COORD_FEATURES + (WINDOW * WINDOW) // 2] = 0.0  # the observer itself
        return obs

    def step(self, actions: npt.ArrayLike) -> StepResult:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        b, n = self.num_envs, self.num_robots
        a = np.asarray(actions)
        if a.shape != (b, n):
            raise ValueError(f"actions must have shape {(b, n)}, got {a.shape}")
        if a.dtype.kind not in "iu":
            if a.dtype.kind == "f" and np.array_equal(a, np.round(a)):
                a = a.astype(np.int64)
            else:
                raise ValueError(f"actions must be integers in [0, {NUM_ACTIONS}), got {a.dtype}")
        if a.size and (a.min() < 0 or a.max() >= NUM_ACTIONS):
            raise ValueError(f"actions must be in [0, {NUM_ACTIONS}), got {a.min()}..{a.max()}")

        af = a.reshape(-1)
        cur = self._cell.reshape(-1)
        moves = self._act_off[af]
        blocked = self._flat[cur + moves] == 1
        new, coll_flat = resolve_moves(cur, moves, blocked, self._occ)

        # commit the moves on the canvas and the occupancy map
        self._flat[cur] = 0
        self._occ[cur] = -1
        self._flat[new] = 2
        self._occ[new] = self._robot_ids
        moved = (new != cur).reshape(b, n)
        self._cell = new.reshape(b, n)
        self._x += np.where(moved, ACTION_DELTAS[a, 0], 0)
        self._y += np.where(moved, ACTION_DELTAS[a, 1], 0)
        coll = coll_flat.reshape(b, n)

        # rewards
        rw = self.rewards
        x, y = self._x, self._y
        dist = np.abs(x - self._gx) + np.abs(y - self._gy)
        on_goal = dist == 0
        all_on = on_goal.all(axis=1)
        stay = a == 0
        r = self._base_reward[np.add(stay, stay & on_goal, dtype=np.intp)]
        r += rw.collision * coll
        r += rw.progress * (dist < self._dist)
        if rw.progress_away:
            r += rw.progress_away * (dist > self._dist)
        inv_n = 1.0 / n
        ex = x - (x.sum(axis=1) * inv_n)[:, None] - self._gox
        ey = y - (y.sum(axis=1) * inv_n)[:, None] - self._goy
        ferr = np.abs(ex) + np.abs(ey)
        r += np.exp(-ferr) * rw.formation_scale - 0.5 * rw.formation_scale
        if all_on.any():
            r += rw.completion * all_on[:, None]
        self._dist = dist
        team = r.sum(axis=1)
        self.robot_rewards = r.astype(np.float32)
        self.robot_collisions = coll

        self._t += 1
        self._ret += team
        self._coll += coll.sum(axis=1)
        self._ferr += ferr.sum(axis=1) * inv_n
        terminated = all_on
        truncated = (self._t >= self.max_steps) & ~terminated
        done = terminated | truncated

        obs = self._observe()
        final_obs = obs
        episodes: list[EpisodeStats] = []
        self.final_worlds = {}
        if done.any():
            final_obs = obs
            for e in np.flatnonzero(done).tolist():
                t = int(self._t[e])
                episodes.append(
                    EpisodeStats(
                        env_index=e,
                        episode_return=float(self._ret[e]),
                        length=t,
                        makespan=t if bool(terminated[e]) else None,
                        completed=bool(terminated[e]),
                        collisions=int(self._coll[e]),
                        formation_error=float(self._ferr[e] / t),
                    )
                )
                self.final_worlds[e] = self.world(e)
                self._reset_env(e)
            obs = self._observe()
        return StepResult(
            obs=obs,
            state=obs.reshape(b, -1),
            reward=team.astype(np.float32),
            terminated=terminated,
            truncated=truncated,
            final_obs=final_obs,
            final_state=final_obs.reshape(b, -1),
            episodes=episodes,
        )

    # ------------------------------------------------------------------ inspection
    def world(self, b: int = 0) -> MaifWorld:
        """A copy of env ``b``'s current world (positions, goals, obstacles, instance, step)."""
        k = int(self._instance[b])
        return MaifWorld(
            positions=np.stack([self._x[b], self._y[b]], axis=1),
            goals=np.stack([self._gx[b], self._gy[b]], axis=1),
            obstacles=self.instances.instance(k)[0].copy(),
            instance_id=k,
            step=int(self._t[b]),
        )

    @property
    def positions(self) -> IntArray:
        """[B, N, 2] (x, y) of every robot (a copy)."""
        return np.stack([self._x, self._y], axis=2)

    @property
    def goals(self) -> IntArray:
        return np.stack([self._gx, self._gy], axis=2)

    @property
    def instance_id(self) -> IntArray:
        """[B] instance id each env is playing."""
        return self._instance.copy()

    @property
    def step_count(self) -> IntArray:
        """[B] steps taken in each env's current episode (the scripted planner's clock)."""
        return self._t.copy()

    def render_rgb(self, b: int = 0, cell_px: int = 8) -> npt.NDArray[np.uint8]:
        return self.world(b).render_rgb(cell_px)
