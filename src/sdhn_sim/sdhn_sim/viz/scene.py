"""Team state, hypergraphs, episode summaries → Foxglove messages (no ROS; live and by replay).

The viz node feeds ROS messages in; replay can feed recorded (decoded) messages in the same way:
everything here duck-types on the field names of ``sdhn_msgs`` (``msg.state``, ``msg.positions``,
``msg.header.stamp.sec`` ...), and takes ``array.array``, NumPy arrays, lists or bytes for arrays.

Frame and units: every entity is in frame ``map``, 1 grid cell = 1 m, z up. Cell ``(x, y)`` (x
right, y down, as in ``sdhn_sim.envs``) covers ``[x, x+1] × [-(y+1), -y]`` in the map frame: the
map's y axis points up, so the grid is seen top-down exactly as ``render_grid`` draws it.
``cell_center`` and ``map_to_cell`` convert.

How the world is known (TeamState carries positions and the global state, not the map):
- MAIF: every robot's goal is in its observation (features 4-5, scaled by ``size - 1``), so the
  goals are exact. The goal pattern identifies the instance in the configuration's fixed
  instance set (``load_instances``), which gives the obstacle map; the map is then checked
  against every robot's 7×7 window in the state. If no instance matches or a window disagrees
  (e.g. a simulator run on a hand-built instance set), the map falls back to what the windows
  have shown in this episode: cells never seen are drawn as "unknown" (faint), seen obstacles as
  obstacles. ``MapEstimate.exact`` says which. A ``uint16 instance_id`` field in TeamState would
  make the lookup unnecessary.
- RWARE: the warehouse layout (shelf racks = non-highway cells, goal cells) is fixed by the task and
  taken from ``rware`` itself; robot direction and "carrying" come from each robot's own observation
  features; shelves are drawn where some robot's 3×3 window currently sees one (requested ones red).
  Shelves nobody sees are not drawn (the state does not contain them).
"""

from __future__ import annotations

import array
import functools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from sdhn_sim.envs.maif import COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS, MaifConfig, load_instances
from sdhn_sim.envs.registry import RWARE_TASKS, env_names
from sdhn_sim.envs.render import robot_colors

FRAME_ID = "map"
TOPIC_SCENE = "/viz/scene"
TOPIC_HYPERGRAPH = "/viz/hypergraph"
TOPIC_P_H = "/viz/hypergraph/p_h"
TOPIC_METRICS = "/viz/metrics"
TOPIC_EPISODES = "/viz/episodes"

METRICS_SCHEMA: dict[str, Any] = {
    "title": "sdhn.VizMetrics",
    "type": "object",
    "properties": {
        "env": {"type": "string"},
        "episode": {"type": "integer"},
        "step": {"type": "integer"},
        "step_rate": {"type": "number", "description": "team states per second (recent)"},
        "team_reward": {"type": "number"},
        "return_so_far": {"type": "number"},
        "makespan_so_far": {"type": "integer"},
        "missed_actions": {"type": "integer"},
        "last_return": {"type": ["number", "null"]},
        "last_makespan": {"type": ["integer", "null"], "description": "null = not completed"},
        "last_collisions": {"type": ["integer", "null"]},
        "episodes_done": {"type": "integer"},
        "policy_version": {"type": "integer", "description": "newest weights version seen"},
        "skewness": {"type": ["number", "null"]},
        "dropped": {"type": "integer", "description": "malformed input messages dropped"},
    },
}
EPISODE_SCHEMA: dict[str, Any] = {
    "title": "sdhn.VizEpisode",
    "type": "object",
    "properties": {
        "env": {"type": "string"},
        "episode": {"type": "integer"},
        "length": {"type": "integer"},
        "completed": {"type": "boolean"},
        "makespan": {"type": ["integer", "null"], "description": "null = not completed (NC)"},
        "episode_return": {"type": "number"},
        "collisions": {"type": "integer"},
        "formation_error": {"type": "number"},
        "missed_actions": {"type": "integer"},
        "policy_version": {"type": "integer"},
    },
}

FloatArray = npt.NDArray[np.float32]
IntArray = npt.NDArray[np.int64]


class BadInput(ValueError):
    """A message that cannot be drawn; ``kind`` is the counter it is dropped under."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


# ----------------------------------------------------------------------------- geometry helpers
def cell_center(x: float, y: float) -> tuple[float, float]:
    """Map-frame (x, y) in metres of the centre of grid cell (x, y)."""
    return float(x) + 0.5, -(float(y) + 0.5)


def map_to_cell(mx: float, my: float) -> tuple[int, int]:
    """Grid cell containing the map-frame point (mx, my)."""
    return math.floor(mx), math.floor(-my)


_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _pose(mx: float, my: float, z: float, yaw: float = 0.0) -> Pose:
    q = _IDENTITY if yaw == 0.0 else Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    return Pose(position=Vector3(x=mx, y=my, z=z), orientation=q)


def _color(rgb: Sequence[float], a: float = 1.0) -> Color:
    return Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(a))


def _palette(n: int) -> list[tuple[float, float, float]]:
    return [(c[0], c[1], c[2]) for c in (robot_colors(n).astype(np.float64) / 255.0).tolist()]


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
    """The static description of ``env_name``; raises ``BadInput('unknown_env')``."""
    if env_name in MAIF_CONFIGS:
        cfg = MAIF_CONFIGS[env_name]
        return WorldInfo(env_name, "maif", cfg.num_robots, OBS_SIZE, cfg.size, cfg.size, maif=cfg)
    if env_name in RWARE_TASKS:
        from sdhn_sim.envs.rware_env import make_rware_gym, rware_env_id

        n = RWARE_TASKS[env_name]
        gym_env = make_rware_gym(rware_env_id(n), 500)
        raw = gym_env.unwrapped
        obs_size = int(gym_env.observation_space[0].shape[0])
        racks = np.asarray(raw.highways) == 0
        goals = tuple((int(x), int(y)) for x, y in raw.goals)
        gym_env.close()
        height, width = racks.shape
        return WorldInfo(
            env_name, "rware", n, obs_size, width, height, rware_racks=racks, rware_goals=goals
        )
    raise BadInput("unknown_env", f"unknown environment {env_name!r}; known: {env_names()}")


@dataclass(frozen=True)
class MapEstimate:
    """A MAIF obstacle map as far as the viewer knows it."""

    obstacles: npt.NDArray[np.bool_]  # [size, size] indexed [y, x]
    known: npt.NDArray[np.bool_]  # cells whose content is known
    instance_id: int  # -1 when the instance could not be identified
    exact: bool


class MaifMapper:
    """Recovers a MAIF map from team states (see the module docstring)."""

    def __init__(self, cfg: MaifConfig) -> None:
        self.cfg = cfg
        self._index: dict[bytes, int] | None = None
        self._last_key: bytes = b""
        self._last: MapEstimate | None = None
        self._seen_obs: npt.NDArray[np.bool_] | None = None
        self._seen_known: npt.NDArray[np.bool_] | None = None

    def _goal_index(self) -> dict[bytes, int]:
        if self._index is None:
            inst = load_instances(self.cfg.name)
            goals = inst.goals.reshape(-1, self.cfg.num_robots, 2).astype(np.int64)
            self._index = {goals[k].tobytes(): k for k in range(goals.shape[0])}
        return self._index

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
        goals = goals_from_state(frame.state, self.cfg)
        key = goals.tobytes() + frame.episode.to_bytes(4, "little")
        obstacle, known = self.observed(frame.state, frame.positions)
        if key == self._last_key and self._last is not None and self._last.exact:
            return self._last
        k = self._goal_index().get(goals.tobytes(), -1)
        if k >= 0:
            grid = load_instances(self.cfg.name).instance(k)[0]
            if np.array_equal(grid[known], obstacle[known]):
                est = MapEstimate(grid, np.ones_like(grid), k, True)
                self._last_key, self._last = key, est
                return est
        # Fallback: accumulate what the windows showed during this episode.
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
        raise BadInput("env_mismatch", f"state of {name!r} but this viewer draws {expected_env!r}")
    n = int(msg.num_robots)
    if n != world.num_robots:
        raise BadInput("wrong_size", f"num_robots={n}, {name} has {world.num_robots}")
    state = _floats(msg.state)
    if state.size != n * world.obs_size:
        raise BadInput("wrong_size", f"state has {state.size} floats, want {n}x{world.obs_size}")
    pos = _ints(msg.positions)
    if pos.size != 2 * n:
        raise BadInput("wrong_size", f"positions has {pos.size} ints, want 2x{n}")
    pos = pos.reshape(n, 2)
    if (
        pos[:, 0].min() < 0
        or pos[:, 1].min() < 0
        or pos[:, 0].max() >= world.width
        or pos[:, 1].max() >= world.height
    ):
        raise BadInput("out_of_grid", f"a position lies outside {world.width}x{world.height}")
    if not np.isfinite(state).all():
        raise BadInput("not_finite", "state holds NaN or Inf")
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
        raise BadInput("wrong_size", f"hypergraph of {n}x{m}")
    if num_robots is not None and n != num_robots:
        raise BadInput("wrong_size", f"hypergraph for {n} robots, the team has {num_robots}")
    p_h = _floats(msg.p_h)
    if p_h.size != n * m:
        raise BadInput("wrong_size", f"p_h has {p_h.size} floats, want {n}x{m}")
    if not np.isfinite(p_h).all() or p_h.min() < 0.0 or p_h.max() > 1.0:
        raise BadInput("bad_value", "p_h outside [0, 1] or not finite")
    inc = _bytes_u8(msg.incidence)
    incidence: npt.NDArray[np.uint8] | None = None
    if inc.size:
        if inc.size != n * m:
            raise BadInput("wrong_size", f"incidence has {inc.size} entries, want {n}x{m}")
        incidence = inc.reshape(n, m)
    skew = float(msg.skewness)
    if not math.isfinite(skew):
        raise BadInput("bad_value", "skewness not finite")
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


# ----------------------------------------------------------------------------- scene building
FLOOR_RGB = (0.93, 0.93, 0.93)
OBSTACLE_RGB = (0.16, 0.16, 0.16)
UNKNOWN_RGB = (0.75, 0.75, 0.80)
RACK_RGB = (0.80, 0.72, 0.55)
SHELF_RGB = (0.55, 0.38, 0.18)
REQUESTED_RGB = (0.85, 0.15, 0.15)
GOAL_RGB = (0.20, 0.65, 0.25)


def _cells_cubes(
    cells: npt.NDArray[np.int64], z: float, height: float, rgb: Sequence[float], a: float = 1.0
) -> list[CubePrimitive]:
    side = 1.0
    size = Vector3(x=side, y=side, z=height)
    color = _color(rgb, a)
    return [
        CubePrimitive(pose=_pose(x + 0.5, -(y + 0.5), z), size=size, color=color)
        for x, y in cells.tolist()
    ]


def _entity(eid: str, stamp: Timestamp | None, **kw: Any) -> SceneEntity:
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=eid, **kw)


def _meta(**kv: Any) -> list[KeyValuePair]:
    return [KeyValuePair(key=k, value=str(v)) for k, v in kv.items()]


def static_entities(frame: TeamFrame, mapper: MaifMapper | None) -> list[SceneEntity]:
    """Floor, obstacles (MAIF) or racks (RWARE), and goal cells."""
    w = frame.world
    st = frame.stamp
    floor = _entity(
        "map/floor",
        st,
        cubes=[
            CubePrimitive(
                pose=_pose(w.width / 2, -w.height / 2, -0.03),
                size=Vector3(x=w.width, y=w.height, z=0.02),
                color=_color(FLOOR_RGB),
            )
        ],
        metadata=_meta(env=w.env_name, width=w.width, height=w.height),
    )
    out = [floor]
    colors = _palette(w.num_robots)
    if w.kind == "maif" and mapper is not None and w.maif is not None:
        est = mapper.estimate(frame)
        ys, xs = np.nonzero(est.obstacles & est.known)
        cubes = _cells_cubes(np.stack([xs, ys], 1), 0.5, 1.0, OBSTACLE_RGB)
        if not est.exact:
            uy, ux = np.nonzero(~est.known)
            cubes += _cells_cubes(np.stack([ux, uy], 1), 0.0, 0.02, UNKNOWN_RGB, 0.6)
        out.append(
            _entity(
                "map/obstacles",
                st,
                cubes=cubes,
                metadata=_meta(instance_id=est.instance_id, exact=est.exact),
            )
        )
        goals = goals_from_state(frame.state, w.maif)
        out.append(
            _entity(
                "map/goals",
                st,
                cubes=[
                    CubePrimitive(
                        pose=_pose(x + 0.5, -(y + 0.5), 0.0),
                        size=Vector3(x=0.9, y=0.9, z=0.02),
                        color=_color([(c + 2.0) / 3.0 for c in colors[i]]),
                    )
                    for i, (x, y) in enumerate(goals.tolist())
                ],
                metadata=_meta(goals=goals.reshape(-1).tolist()),
            )
        )
    elif w.kind == "rware" and w.rware_racks is not None:
        ys, xs = np.nonzero(w.rware_racks)
        out.append(
            _entity("map/racks", st, cubes=_cells_cubes(np.stack([xs, ys], 1), 0.0, 0.02, RACK_RGB))
        )
        gl = np.asarray(w.rware_goals, dtype=np.int64).reshape(-1, 2)
        out.append(_entity("map/goals", st, cubes=_cells_cubes(gl, 0.0, 0.03, GOAL_RGB)))
    return out


def rware_seen_shelves(frame: TeamFrame) -> tuple[IntArray, npt.NDArray[np.bool_]]:
    """Cells (x, y) where some robot's window shows a shelf, and whether it is requested."""
    n, d = frame.state.shape
    cells_per_robot = (d - RWARE_SELF_BITS) // RWARE_CELL_BITS
    side = math.isqrt(cells_per_robot)
    if side * side != cells_per_robot:
        return np.zeros((0, 2), np.int64), np.zeros(0, bool)
    blocks = frame.state[:, RWARE_SELF_BITS:].reshape(n, side, side, RWARE_CELL_BITS)
    r = side // 2
    off = np.arange(side) - r
    xs = np.broadcast_to(frame.positions[:, 0, None, None] + off[None, None, :], blocks.shape[:3])
    ys = np.broadcast_to(frame.positions[:, 1, None, None] + off[None, :, None], blocks.shape[:3])
    has = blocks[..., 5] > 0.5
    inside = (xs >= 0) & (xs < frame.world.width) & (ys >= 0) & (ys < frame.world.height) & has
    cells = np.stack([xs[inside], ys[inside]], 1)
    req = blocks[..., 6][inside] > 0.5
    uniq, first = np.unique(cells, axis=0, return_index=True)
    return uniq.astype(np.int64), req[first]


def robot_entities(frame: TeamFrame, trail: Sequence[IntArray]) -> list[SceneEntity]:
    """One entity per robot: body, id label, short trail (and heading/load for RWARE)."""
    w = frame.world
    st = frame.stamp
    colors = _palette(w.num_robots)
    hist = np.stack(list(trail), axis=0) if trail else frame.positions[None]  # [T, N, 2]
    out = []
    rware = w.kind == "rware"
    for i, (x, y) in enumerate(frame.positions.tolist()):
        mx, my = x + 0.5, -(y + 0.5)
        col = _color(colors[i])
        body = Vector3(x=0.7, y=0.7, z=0.6)
        cubes = [CubePrimitive(pose=_pose(mx, my, 0.3), size=body, color=col)]
        arrows = []
        meta: dict[str, Any] = {"robot_id": i, "x": x, "y": y}
        if rware:
            row = frame.state[i]
            heading = int(np.argmax(row[3:7]))
            carrying = bool(row[2] > 0.5)
            arrows.append(
                ArrowPrimitive(
                    pose=_pose(mx, my, 0.65, RWARE_YAW[heading]),
                    shaft_length=0.3,
                    shaft_diameter=0.08,
                    head_length=0.2,
                    head_diameter=0.2,
                    color=_color((0.1, 0.1, 0.1)),
                )
            )
            if carrying:
                cubes.append(
                    CubePrimitive(
                        pose=_pose(mx, my, 0.75), size=Vector3(x=0.8, y=0.8, z=0.3),
                        color=_color(SHELF_RGB),
                    )
                )
            meta.update(heading=("up", "down", "left", "right")[heading], carrying=carrying)
        pts = [Point3(x=px + 0.5, y=-(py + 0.5), z=0.05) for px, py in hist[:, i].tolist()]
        lines = (
            [LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.12, points=pts,
                           color=_color(colors[i], 0.6))]
            if len(pts) > 1
            else []
        )
        out.append(
            _entity(
                f"robot/{i}",
                st,
                cubes=cubes,
                arrows=arrows,
                lines=lines,
                texts=[
                    TextPrimitive(
                        pose=_pose(mx, my, 1.1), billboard=True, font_size=14.0,
                        scale_invariant=True, color=_color((0.0, 0.0, 0.0)), text=str(i),
                    )
                ],
                metadata=_meta(**meta),
            )
        )
    if rware:
        cells, req = rware_seen_shelves(frame)
        cubes = [
            CubePrimitive(
                pose=_pose(x + 0.5, -(y + 0.5), 0.25), size=Vector3(x=0.8, y=0.8, z=0.5),
                color=_color(REQUESTED_RGB if r else SHELF_RGB, 0.9),
            )
            for (x, y), r in zip(cells.tolist(), req.tolist(), strict=True)
        ]
        out.append(_entity("shelves/seen", st, cubes=cubes, metadata=_meta(count=len(cubes))))
    return out


def hypergraph_entities(hf: HyperFrame, positions: IntArray) -> list[SceneEntity]:
    """One entity per hyperedge: a star from the P_H-weighted centre to its robots.

    Lines to robots in the sampled incidence H are thick; other robots with P_H >= 0.05 thin;
    every line's opacity is that robot's P_H. A ``hypergraph`` entity carries skewness and sizes.
    """
    n, m = hf.p_h.shape
    st = hf.stamp
    edge_colors = _palette(m)
    centers = np.stack([positions[:, 0] + 0.5, -(positions[:, 1] + 0.5)], 1).astype(np.float64)
    out = [
        _entity(
            "hypergraph",
            st,
            metadata=_meta(
                skewness=f"{hf.skewness:.4f}", num_robots=n, num_hyperedges=m,
                episode=hf.episode, step=hf.step, policy_version=hf.policy_version,
            ),
        )
    ]
    members = hf.incidence.astype(bool) if hf.incidence is not None else hf.p_h >= 0.5
    for j in range(m):
        p = hf.p_h[:, j].astype(np.float64)
        total = p.sum()
        c = (p[:, None] * centers).sum(0) / total if total > 1e-9 else centers.mean(0)
        hub = Point3(x=float(c[0]), y=float(c[1]), z=1.4)
        prims = []
        for thick, sel in ((0.1, members[:, j]), (0.03, ~members[:, j] & (p >= 0.05))):
            idx = np.flatnonzero(sel)
            if idx.size == 0:
                continue
            pts: list[Point3] = []
            cols: list[Color] = []
            for i in idx.tolist():
                pts += [hub, Point3(x=float(centers[i, 0]), y=float(centers[i, 1]), z=0.6)]
                col = _color(edge_colors[j], max(0.1, p[i]))
                cols += [col, col]
            prims.append(
                LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=thick, points=pts,
                              colors=cols, color=_color(edge_colors[j]))
            )
        out.append(
            _entity(
                f"hyperedge/{j}",
                st,
                lines=prims,
                metadata=_meta(
                    degree=int(members[:, j].sum()), mean_p=f"{p.mean():.3f}",
                    skewness=f"{hf.skewness:.4f}",
                ),
            )
        )
    return out


# viridis, 5 stops
_VIRIDIS = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64
)


def heatmap_rgb(values: FloatArray, cell_px: int = 12) -> npt.NDArray[np.uint8]:
    """[rows*cell_px, cols*cell_px, 3] viridis image of values in [0, 1] (row = robot)."""
    v = np.clip(values.astype(np.float64), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    lo = np.floor(v).astype(np.int64).clip(0, len(_VIRIDIS) - 2)
    f = (v - lo)[..., None]
    rgb = (_VIRIDIS[lo] * (1 - f) + _VIRIDIS[lo + 1] * f).round().astype(np.uint8)
    return np.repeat(np.repeat(rgb, cell_px, axis=0), cell_px, axis=1)


def p_h_image(hf: HyperFrame, cell_px: int = 12) -> RawImage:
    """RawImage (rgb8) of P_H: one row of cells per robot, one column per hyperedge."""
    img = heatmap_rgb(hf.p_h, cell_px)
    h, w, _ = img.shape
    return RawImage(
        timestamp=hf.stamp, frame_id="p_h", width=w, height=h, encoding="rgb8", step=3 * w,
        data=img.tobytes(),
    )


# ----------------------------------------------------------------------------- stateful renderer
@dataclass
class _Metrics:
    rate_times: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    return_so_far: float = 0.0
    episode: int = -1
    last_return: float | None = None
    last_makespan: int | None = None
    last_collisions: int | None = None
    episodes_done: int = 0
    policy_version: int = 0
    skewness: float | None = None


class VizRenderer:
    """Keeps what drawing needs across messages (trail, last positions, map, metrics).

    Live (viz node) and offline (replay) use it the same way: call ``on_state`` /
    ``on_hypergraph`` / ``on_episode`` for every message in order (cheap bookkeeping; raise
    ``BadInput``), then build only the outputs somebody wants with ``scene``, ``hypergraph_scene``,
    ``p_h_image``, ``metrics``. ``render`` does both for replay.
    """

    def __init__(self, env: str = "", trail_length: int = 12) -> None:
        self.env = env
        self.trail: deque[IntArray] = deque(maxlen=max(1, trail_length))
        self.frame: TeamFrame | None = None
        self.hyper: HyperFrame | None = None
        self._mapper: MaifMapper | None = None
        self._m = _Metrics()
        self.dropped = 0

    # -- bookkeeping (every message)
    def on_state(self, msg: Any, now_s: float | None = None) -> TeamFrame:
        frame = parse_team_state(msg, self.env)
        prev = self.frame
        if prev is None or prev.episode != frame.episode or frame.step < prev.step:
            self.trail.clear()
            self._m.return_so_far = 0.0
        if prev is None or prev.env_name != frame.env_name:
            cfg = frame.world.maif
            self._mapper = MaifMapper(cfg) if cfg is not None else None
        self.trail.append(frame.positions)
        if frame.step > 0:
            self._m.return_so_far += frame.team_reward
        self._m.episode = frame.episode
        self._m.rate_times.append(frame.stamp_ns / 1e9 if now_s is None else now_s)
        self.frame = frame
        return frame

    def on_hypergraph(self, msg: Any) -> HyperFrame:
        n = self.frame.world.num_robots if self.frame is not None else None
        hf = parse_hypergraph(msg, n)
        self.hyper = hf
        self._m.skewness = hf.skewness
        self._m.policy_version = max(self._m.policy_version, hf.policy_version)
        return hf

    def on_episode(self, msg: Any) -> dict[str, Any]:
        name = str(msg.env_name)
        if self.env and name != self.env:
            raise BadInput(
                "env_mismatch", f"episode of {name!r} but this viewer draws {self.env!r}"
            )
        completed = bool(msg.completed)
        out: dict[str, Any] = {
            "env": name,
            "episode": int(msg.episode),
            "length": int(msg.length),
            "completed": completed,
            "makespan": int(msg.makespan) if completed else None,
            "episode_return": float(msg.episode_return),
            "collisions": int(msg.collisions),
            "formation_error": float(msg.formation_error),
            "missed_actions": int(msg.missed_actions),
            "policy_version": int(msg.policy_version),
        }
        m = self._m
        m.last_return, m.last_makespan = out["episode_return"], out["makespan"]
        m.last_collisions = out["collisions"]
        m.episodes_done += 1
        m.policy_version = max(m.policy_version, out["policy_version"])
        return out

    # -- outputs (only when wanted)
    def scene(self, with_static: bool = True) -> SceneUpdate:
        """Robots with labels and trails; with the floor, obstacles/racks and goals if asked."""
        if self.frame is None:
            return SceneUpdate()
        entities = static_entities(self.frame, self._mapper) if with_static else []
        entities += robot_entities(self.frame, self.trail)
        return SceneUpdate(entities=entities)

    def map_estimate(self) -> MapEstimate | None:
        if self.frame is None or self._mapper is None:
            return None
        return self._mapper.estimate(self.frame)

    def hypergraph_scene(self) -> SceneUpdate | None:
        """Hyperedges between the robots' latest positions; None before both are known."""
        if self.hyper is None or self.frame is None:
            return None
        if self.hyper.num_robots != self.frame.positions.shape[0]:
            return None
        return SceneUpdate(entities=hypergraph_entities(self.hyper, self.frame.positions))

    def p_h_image(self, cell_px: int = 12) -> RawImage | None:
        return None if self.hyper is None else p_h_image(self.hyper, cell_px)

    def metrics(self) -> dict[str, Any]:
        m, f = self._m, self.frame
        times = m.rate_times
        span = times[-1] - times[0] if len(times) > 1 else 0.0
        return {
            "env": f.env_name if f else self.env,
            "episode": f.episode if f else 0,
            "step": f.step if f else 0,
            "step_rate": (len(times) - 1) / span if span > 0 else 0.0,
            "team_reward": f.team_reward if f else 0.0,
            "return_so_far": m.return_so_far,
            "makespan_so_far": f.makespan_so_far if f else 0,
            "missed_actions": f.missed_actions if f else 0,
            "last_return": m.last_return,
            "last_makespan": m.last_makespan,
            "last_collisions": m.last_collisions,
            "episodes_done": m.episodes_done,
            "policy_version": m.policy_version,
            "skewness": m.skewness,
            "dropped": self.dropped,
        }

    def render(self, kind: str, msg: Any) -> list[tuple[str, Any]]:
        """For replay: feed one recorded message (``kind`` = state | hypergraph | episode) and get
        every viz message it produces as (topic, message); Foxglove messages have ``.encode()``
        and ``get_schema()``, dicts are JSON (schemas ``METRICS_SCHEMA``/``EPISODE_SCHEMA``)."""
        if kind == "state":
            self.on_state(msg)
            return [(TOPIC_SCENE, self.scene()), (TOPIC_METRICS, self.metrics())]
        if kind == "hypergraph":
            self.on_hypergraph(msg)
            out: list[tuple[str, Any]] = []
            scene = self.hypergraph_scene()
            if scene is not None:
                out.append((TOPIC_HYPERGRAPH, scene))
            out.append((TOPIC_P_H, self.p_h_image()))
            return out
        if kind == "episode":
            return [(TOPIC_EPISODES, self.on_episode(msg))]
        raise ValueError(f"kind must be state, hypergraph or episode, got {kind!r}")
