"""Grid cells as standard map-frame poses, and the cell a robot's action leads to (no ROS).

The convention is the viewer's (:mod:`sdhn_sim.viz.draw`): frame ``map``, 1 cell = 1 m, z up;
cell ``(x, y)`` (x right, y down, as in ``sdhn_sim.envs``) has its centre at ``(x + 0.5,
-(y + 0.5))``, so the map's y axis points up. A yaw of 0 faces +x (right), pi/2 faces up.

An actor only has its own observation, so where it is comes from there: MAIF scales the cell by
``1 / (size - 1)`` (features 0-1; the size comes from the environment's name), RWARE carries the
cell and heading as they are (self block: x, y, carrying, heading one-hot up/down/left/right).
:func:`target_reader` gives the decoder of one environment, or None for a name it does not know.

    reader = target_reader("maif-10")
    x, y, yaw = reader(obs, action)          # map-frame metres and radians of the target cell
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

FRAME_ID = "map"
TargetReader = Callable[[npt.NDArray[np.float32], int], tuple[float, float, float]]

# RWARE headings in observation order (up, down, left, right): map-frame yaw and grid step.
_RWARE_YAW = (math.pi / 2, -math.pi / 2, math.pi, 0.0)
_RWARE_STEP = ((0, -1), (0, 1), (-1, 0), (1, 0))
_RWARE_LEFT = (2, 3, 1, 0)  # heading after turning left: up->left, down->right, left->down, ...
_RWARE_RIGHT = (3, 2, 0, 1)
_RWARE_FORWARD, _RWARE_TURN_LEFT, _RWARE_TURN_RIGHT = 1, 2, 3


def cell_center(x: float, y: float) -> tuple[float, float]:
    """Map-frame (x, y) in metres of the centre of grid cell (x, y)."""
    return float(x) + 0.5, -(float(y) + 0.5)


def yaw_quaternion(yaw: float) -> tuple[float, float]:
    """(z, w) of the quaternion of a rotation by ``yaw`` about z (x = y = 0)."""
    return math.sin(yaw / 2), math.cos(yaw / 2)


def maif_target(size: int) -> TargetReader:
    from sdhn_sim.envs.maif import ACTION_DELTAS

    scale = size - 1

    def target(obs: npt.NDArray[np.float32], action: int) -> tuple[float, float, float]:
        x, y = round(float(obs[0]) * scale), round(float(obs[1]) * scale)
        dx, dy = (int(v) for v in ACTION_DELTAS[action])
        mx, my = cell_center(x + dx, y + dy)
        # facing the move (grid y down = map -y); 'stay' keeps yaw 0
        return mx, my, math.atan2(-dy, dx) if (dx or dy) else 0.0

    return target


def rware_target(obs: npt.NDArray[np.float32], action: int) -> tuple[float, float, float]:
    x, y = round(float(obs[0])), round(float(obs[1]))
    heading = int(np.argmax(obs[3:7]))
    if action == _RWARE_FORWARD:
        dx, dy = _RWARE_STEP[heading]
        x, y = x + dx, y + dy
    elif action == _RWARE_TURN_LEFT:
        heading = _RWARE_LEFT[heading]
    elif action == _RWARE_TURN_RIGHT:
        heading = _RWARE_RIGHT[heading]
    mx, my = cell_center(x, y)
    return mx, my, _RWARE_YAW[heading]


def target_reader(env: str) -> TargetReader | None:
    """The target decoder of environment ``env`` (a registry name); None when unknown. The
    environments are imported here, not with this module: an actor without ``env`` (or the
    simulator's poses) does not pay for them at start."""
    from sdhn_sim.envs.maif_instances import MAIF_CONFIGS
    from sdhn_sim.envs.registry import RWARE_TASKS

    if env in MAIF_CONFIGS:
        return maif_target(MAIF_CONFIGS[env].size)
    if env in RWARE_TASKS:
        return rware_target
    return None
