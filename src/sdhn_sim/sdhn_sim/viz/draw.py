"""Foxglove entities of a team: the static map, robots with trails, hyperedges, the P_H image.

Frame and units: every entity is in frame ``map``, 1 grid cell = 1 m, z up. Cell ``(x, y)`` (x
right, y down, as in ``sdhn_sim.envs``) covers ``[x, x+1] × [-(y+1), -y]`` in the map frame: the
map's y axis points up, so the grid is seen top-down exactly as ``render_grid`` draws it.
``cell_center`` and ``map_to_cell`` convert. Pure functions of parsed frames (:mod:`.world`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
    TextPrimitive,
    Timestamp,
    Vector3,
)

from sdhn_sim.envs.render import robot_colors
from sdhn_sim.viz.world import (
    RWARE_CELL_BITS,
    RWARE_SELF_BITS,
    RWARE_YAW,
    FloatArray,
    HyperFrame,
    IntArray,
    MaifMap,
    TeamFrame,
    goals_from_state,
)

FRAME_ID = "map"


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


def static_entities(frame: TeamFrame, mapper: MaifMap | None) -> list[SceneEntity]:
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

