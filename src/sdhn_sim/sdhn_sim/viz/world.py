"""What the viewer knows about a team's world, and validated input (no ROS; live and by replay).

Everything here duck-types on the field names of ``sdhn_msgs`` (``msg.state``, ``msg.positions``,
``msg.header.stamp.sec`` ...), and takes ``array.array``, NumPy arrays, lists or bytes for arrays,
so the viz node's ROS messages and replay's decoded recordings go through the same parsers.

How the world is known (TeamState carries positions, the global state and the world's identity):
- MAIF: ``TeamState.instance_id`` names the instance in the configuration's fixed instance set
  (``load_instances``), which gives the obstacle map; the map is checked against every robot's
  7×7 window in the state. Every robot's goal is in its observation (features 4-5, scaled by
  ``size - 1``), so the goals are exact. Without an id (-1: a recording made before TeamState
  carried it) or when a window disagrees with the named map (a simulator run on a hand-built
  instance set), the map is only what the windows have shown in this episode: cells never seen
  are drawn as "unknown" (faint), seen obstacles as obstacles. ``MapEstimate.exact`` says which.
  Nothing is inferred from goal or start patterns.
- RWARE: the warehouse layout (shelf racks = non-highway cells, goal cells) is fixed by the task and
  taken from ``rware`` itself; robot direction and "carrying" come from each robot's own observation
  features; shelves are drawn where some robot's 3×3 window currently sees one (requested ones red).
  Shelves nobody sees are not drawn (the state does not contain them).
"""

from __future__ import annotations

import array
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from foxglove.messages import Timestamp

from sdhn_base.drops import DropKind
from sdhn_sim.envs.maif import COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS, MaifConfig, load_instances
from sdhn_sim.envs.registry import RWARE_TASKS, env_names, rware_task_size

FloatArray = npt.NDArray[np.float32]
IntArray = npt.NDArray[np.int64]


class BadInput(ValueError):
    """A message that cannot be drawn; ``kind`` is the counter it is dropped under."""

    def __init__(self, kind: DropKind, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


def _stamp(msg: Any) -> Timestamp | None:
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    return Timestamp(int(stamp.sec), int(getattr(stamp, "nanosec", 0)))


def stamp_ns(msg: Any) -> int:
    """Header stamp of ``msg`` in nanoseconds (0 when it has none)."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is None:
        return 0
    return int(stamp.sec) * 1_000_000_000 + int(getattr(stamp, "nanosec", 0))


def _floats(values: Any) -> FloatArray:
    if isinstance(values, array.array) and values.typecode == "f":
        return np.frombuffer(values, dtype=np.float32)
    return np.asarray(values, dtype=np.float32).reshape(-1)


def _ints(values: Any) -> IntArray:
    return np.asarray(values, dtype=np.int64).reshape(-1)


def _bytes_u8(values: Any) -> npt.NDArray[np.uint8]:
    if isinstance(values, bytes | bytearray | memoryview):
        return np.frombuffer(values, dtype=np.uint8)
    if isinstance(values, list) and values and isinstance(values[0], bytes):
        return np.frombuffer(b"".join(values), dtype=np.uint8)  # rclpy's uint8[] as list[bytes]
    return np.asarray(values, dtype=np.uint8).reshape(-1)


# ----------------------------------------------------------------------------- worlds
@dataclass(frozen=True)
class WorldInfo:
    """What the viewer knows about an environment by name alone."""

    env_name: str
    kind: str  # "maif" | "rware"
    num_robots: int
    obs_size: int
    width: int  # cells along x
    height: int  # cells along y
    maif: MaifConfig | None = None
    rware_racks: npt.NDArray[np.bool_] | None = None  # [height, width] shelf-rack cells
    rware_goals: tuple[tuple[int, int], ...] = ()


# rware's fast flattened observation: self block, then per window cell agent bits + shelf bits.
RWARE_SELF_BITS = 8  # x, y, carrying, direction one-hot (4: up, down, left, right), on highway
RWARE_CELL_BITS = 7  # has agent, direction one-hot (4), has shelf, shelf requested
RWARE_YAW = (math.pi / 2, -math.pi / 2, math.pi, 0.0)  # up, down, left, right in the map frame


@functools.lru_cache(maxsize=16)
def world_info(env_name: str) -> WorldInfo:
    """The static description of ``env_name``; raises ``BadInput(DropKind.UNKNOWN_ENV)``."""
    if env_name in MAIF_CONFIGS:
        cfg = MAIF_CONFIGS[env_name]
        return WorldInfo(env_name, "maif", cfg.num_robots, OBS_SIZE, cfg.size, cfg.size, maif=cfg)
    if env_name in RWARE_TASKS:
        from sdhn_sim.envs.rware_env import make_rware_gym, rware_env_id

        n = RWARE_TASKS[env_name]
        gym_env = make_rware_gym(rware_env_id(n, rware_task_size(env_name)), 500)
        raw = gym_env.unwrapped
        obs_size = int(gym_env.observation_space[0].shape[0])
        racks = np.asarray(raw.highways) == 0
        goals = tuple((int(x), int(y)) for x, y in raw.goals)
        gym_env.close()
        height, width = racks.shape
        return WorldInfo(
            env_name, "rware", n, obs_size, width, height, rware_racks=racks, rware_goals=goals
        )
    raise BadInput(DropKind.UNKNOWN_ENV, f"unknown environment {env_name!r}; known: {env_names()}")


@dataclass(frozen=True)
class MapEstimate:
    """A MAIF obstacle map as far as the viewer knows it."""

    obstacles: npt.NDArray[np.bool_]  # [size, size] indexed [y, x]
    known: npt.NDArray[np.bool_]  # cells whose content is known
    instance_id: int  # -1 when the map is not an instance's (no id, or the windows disagree)
    exact: bool


class MaifMap:
    """The obstacle map of MAIF team states, from the instance id they carry (module docstring)."""

    def __init__(self, cfg: MaifConfig) -> None:
        self.cfg = cfg
        self._last_key: tuple[int, int] = (-1, -2)
        self._last: MapEstimate | None = None
        self._seen_obs: npt.NDArray[np.bool_] | None = None
        self._seen_known: npt.NDArray[np.bool_] | None = None

    def observed(
        self, state: FloatArray, positions: IntArray
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """(obstacle, known) grids of what the robots' windows show in this state."""
        s = self.cfg.size
        win = state[:, COORD_FEATURES:OBS_SIZE].reshape(-1, WINDOW, WINDOW)
        off = np.arange(WINDOW) - RADIUS
        xs = positions[:, 0, None, None] + off[None, None, :]
        ys = positions[:, 1, None, None] + off[None, :, None]
        xs, ys = np.broadcast_to(xs, win.shape), np.broadcast_to(ys, win.shape)
        inside = (xs >= 0) & (xs < s) & (ys >= 0) & (ys < s)
        obstacle = np.zeros((s, s), dtype=bool)
        known = np.zeros((s, s), dtype=bool)
        known[ys[inside], xs[inside]] = True
        hit = inside & (win == 1)
        obstacle[ys[hit], xs[hit]] = True
        return obstacle, known

    def estimate(self, frame: TeamFrame) -> MapEstimate:
        key = (frame.episode, frame.instance_id)
        if key == self._last_key and self._last is not None and self._last.exact:
            return self._last
        obstacle, known = self.observed(frame.state, frame.positions)
        k = frame.instance_id
        inst = load_instances(self.cfg.name) if k >= 0 else None
        if inst is not None and k < inst.num_instances:
            grid = inst.instance(k)[0]
            if np.array_equal(grid[known], obstacle[known]):
                est = MapEstimate(grid, np.ones_like(grid), k, True)
                self._last_key, self._last = key, est
                return est
        # No id (an old recording) or a map the windows contradict: what the windows showed in
        # this episode, accumulated.
        if key != self._last_key or self._seen_obs is None or self._seen_known is None:
            self._seen_obs = np.zeros_like(obstacle)
            self._seen_known = np.zeros_like(known)
        self._seen_obs[known] = obstacle[known]
        self._seen_known |= known
        est = MapEstimate(self._seen_obs.copy(), self._seen_known.copy(), -1, False)
        self._last_key, self._last = key, est
        return est


def goals_from_state(state: FloatArray, cfg: MaifConfig) -> IntArray:
    """[N, 2] goal cells (x, y) read from the robots' observation features 4-5."""
    return np.rint(state[:, 4:6].astype(np.float64) * (cfg.size - 1)).astype(np.int64)


# ----------------------------------------------------------------------------- parsed input
@dataclass
class TeamFrame:
    """A validated TeamState."""

    world: WorldInfo
    episode: int
    step: int
    positions: IntArray  # [N, 2] (x, y)
    state: FloatArray  # [N, obs_size]
    team_reward: float
    terminated: bool
    truncated: bool
    makespan_so_far: int
    missed_actions: int
    instance_id: int  # the world's instance (MAIF); -1 = not known (RWARE, old recordings)
    stamp: Timestamp | None = None
    stamp_ns: int = 0

    @property
    def env_name(self) -> str:
        return self.world.env_name


def parse_team_state(msg: Any, expected_env: str = "") -> TeamFrame:
    """Validate a TeamState (ROS or decoded recording); raises ``BadInput`` naming the problem."""
    name = str(msg.env_name)
    world = world_info(name)
    if expected_env and name != expected_env:
        raise BadInput(DropKind.ENV_MISMATCH,
                       f"state of {name!r} but this viewer draws {expected_env!r}")
    n = int(msg.num_robots)
    if n != world.num_robots:
        raise BadInput(DropKind.WRONG_TEAM_SIZE, f"num_robots={n}, {name} has {world.num_robots}")
    state = _floats(msg.state)
    if state.size != n * world.obs_size:
        raise BadInput(DropKind.WRONG_STATE_LENGTH,
                       f"state has {state.size} floats, want {n}x{world.obs_size}")
    pos = _ints(msg.positions)
    if pos.size != 2 * n:
        raise BadInput(DropKind.WRONG_SIZE, f"positions has {pos.size} ints, want 2x{n}")
    pos = pos.reshape(n, 2)
    if (
        pos[:, 0].min() < 0
        or pos[:, 1].min() < 0
        or pos[:, 0].max() >= world.width
        or pos[:, 1].max() >= world.height
    ):
        raise BadInput(DropKind.OUT_OF_GRID,
                       f"a position lies outside {world.width}x{world.height}")
    if not np.isfinite(state).all():
        raise BadInput(DropKind.NON_FINITE_STATE, "state holds NaN or Inf")
    return TeamFrame(
        world=world,
        episode=int(msg.episode),
        step=int(msg.step),
        positions=pos,
        state=state.reshape(n, world.obs_size),
        team_reward=float(msg.team_reward),
        terminated=bool(msg.terminated),
        truncated=bool(msg.truncated),
        makespan_so_far=int(msg.makespan_so_far),
        missed_actions=int(msg.missed_actions),
        instance_id=int(msg.instance_id),
        stamp=_stamp(msg),
        stamp_ns=stamp_ns(msg),
    )


@dataclass
class HyperFrame:
    """A validated Hypergraph."""

    episode: int
    step: int
    p_h: FloatArray  # [N, M]
    incidence: npt.NDArray[np.uint8] | None  # [N, M] or None when not sent
    skewness: float
    policy_version: int
    stamp: Timestamp | None = None
    stamp_ns: int = 0

    @property
    def num_robots(self) -> int:
        return int(self.p_h.shape[0])

    @property
    def num_hyperedges(self) -> int:
        return int(self.p_h.shape[1])


def parse_hypergraph(msg: Any, num_robots: int | None = None) -> HyperFrame:
    """Validate a Hypergraph; ``num_robots`` (when known) must match N."""
    n, m = int(msg.num_robots), int(msg.num_hyperedges)
    if n < 1 or m < 1:
        raise BadInput(DropKind.WRONG_SIZE, f"hypergraph of {n}x{m}")
    if num_robots is not None and n != num_robots:
        raise BadInput(DropKind.WRONG_TEAM_SIZE,
                       f"hypergraph for {n} robots, the team has {num_robots}")
    p_h = _floats(msg.p_h)
    if p_h.size != n * m:
        raise BadInput(DropKind.WRONG_SIZE, f"p_h has {p_h.size} floats, want {n}x{m}")
    if not np.isfinite(p_h).all() or p_h.min() < 0.0 or p_h.max() > 1.0:
        raise BadInput(DropKind.BAD_VALUE, "p_h outside [0, 1] or not finite")
    inc = _bytes_u8(msg.incidence)
    incidence: npt.NDArray[np.uint8] | None = None
    if inc.size:
        if inc.size != n * m:
            raise BadInput(DropKind.WRONG_SIZE, f"incidence has {inc.size} entries, want {n}x{m}")
        incidence = inc.reshape(n, m)
    skew = float(msg.skewness)
    if not math.isfinite(skew):
        raise BadInput(DropKind.BAD_VALUE, "skewness not finite")
    return HyperFrame(
        episode=int(msg.episode),
        step=int(msg.step),
        p_h=p_h.reshape(n, m),
        incidence=incidence,
        skewness=skew,
        policy_version=int(msg.policy_version),
        stamp=_stamp(msg),
        stamp_ns=stamp_ns(msg),
    )

