"""Actor input features: a named, versioned transform of one robot's own raw observation.

NumPy only (actor processes import this; never torch). The actor and the critic see the same
per-robot features; the critic's state is the concatenation of the N robots' features.

    fn = get_transform("maif-ego/1")
    x = fn(obs)                    # obs [..., 57] -> features [..., feature_size("maif-ego/1", 57)]

``identity`` (RWARE, and any env without a named transform) passes the observation through.

``maif-ego/1`` turns MAIF's 57 floats ``[x, y, mx, my, gx, gy, mgx, mgy] + 7x7 window`` (coordinates
divided by ``size - 1``; window 0 free, 1 obstacle/outside, 2 robot) into, in this order:

====  ==========================================================================================
 2    egocentric goal offset ``(gx - x, gy - y)`` (normalised units)
 2    its signs (-1, 0, +1): the direction to the goal, independent of the map size
 1    L1 distance to the goal (normalised)
 1    on-goal flag (1 when the robot stands on its goal)
 2    formation error: own offset from the team centroid minus the goal's offset from the goal
      centroid, ``(x - mx) - (gx - mgx)`` and the same for y
 2    its signs
 2    team progress: goal centroid minus team centroid ``(mgx - mx, mgy - my)``
 4    move blocked flags for up, down, left, right (obstacle, wall or robot in that cell)
 49   window: obstacle or outside (1 / 0)
 49   window: another robot (1 / 0)
====  ==========================================================================================

114 floats. Absolute coordinates are left out on purpose: with them a single robot does not
learn to reach its goal in 300 k steps (issue 13); the egocentric offset makes it trivial.
Changing any feature means a new name (``maif-ego/2``): weights record the name they were
trained with, and a runtime refuses names it does not know.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
Transform = Callable[[npt.ArrayLike], F32]

IDENTITY = "identity"
MAIF_EGO = "maif-ego/1"
MAIF_OBS_SIZE = 57
_WIN = 7
_COORDS = 8
# flat window indices of the 4 neighbours, in action order up (y-1), down (y+1), left, right
_CENTRE = 3 * _WIN + 3
_NEIGHBOURS = np.array([_CENTRE - _WIN, _CENTRE + _WIN, _CENTRE - 1, _CENTRE + 1])
_ON_GOAL_EPS = 1e-4  # coordinates are multiples of 1 / (size - 1) >= 1 / 95
_EGO_SIZE = 12 + 4 + 2 * (MAIF_OBS_SIZE - _COORDS)


def identity(obs: npt.ArrayLike) -> F32:
    return np.asarray(obs, dtype=np.float32)


def maif_ego(obs: npt.ArrayLike) -> F32:
    """``maif-ego/1`` (see the module docstring): [..., 57] -> [..., 114].

    Every part is computed into its slice of one output array (the same float32 operations as
    stacking and concatenating the parts, so the same bits): an actor calls this once per step
    for one row, where each temporary array and each extra NumPy call costs more than the
    arithmetic."""
    o = np.asarray(obs, dtype=np.float32)
    if o.shape[-1] != MAIF_OBS_SIZE:
        raise ValueError(f"{MAIF_EGO} needs observations of length {MAIF_OBS_SIZE}, "
                         f"got {o.shape[-1]}")
    out = np.empty((*o.shape[:-1], _EGO_SIZE), dtype=np.float32)
    pos, mpos, goal, mgoal = o[..., 0:2], o[..., 2:4], o[..., 4:6], o[..., 6:8]
    d = np.subtract(goal, pos, out=out[..., 0:2])  # dx, dy
    np.sign(d, out=out[..., 2:4])
    ad = np.abs(d)
    l1 = np.add(ad[..., 0], ad[..., 1], out=out[..., 4])
    out[..., 5] = l1 < _ON_GOAL_EPS  # on_goal
    f = np.subtract(pos - mpos, goal - mgoal, out=out[..., 6:8])  # fx, fy
    np.sign(f, out=out[..., 8:10])
    np.subtract(mgoal, mpos, out=out[..., 10:12])
    win = o[..., _COORDS:]
    cells = MAIF_OBS_SIZE - _COORDS
    out[..., 12:16] = win[..., _NEIGHBOURS] != 0.0  # blocked
    out[..., 16:16 + cells] = win == 1.0  # obstacle
    out[..., 16 + cells:] = win == 2.0  # robot
    return out


TRANSFORMS: dict[str, Transform] = {IDENTITY: identity, MAIF_EGO: maif_ego}
_SIZES: dict[str, Callable[[int], int]] = {
    IDENTITY: lambda d: d,
    MAIF_EGO: lambda d: 12 + 4 + 2 * (d - _COORDS),
}


def check_transform(name: str, obs_size: int) -> None:
    """ValueError unless ``name`` is known and accepts observations of length ``obs_size``."""
    if name not in TRANSFORMS:
        raise ValueError(f"unknown feature transform {name!r}; known: {sorted(TRANSFORMS)}")
    if name == MAIF_EGO and obs_size != MAIF_OBS_SIZE:
        raise ValueError(f"{MAIF_EGO} needs observations of length {MAIF_OBS_SIZE}, "
                         f"not {obs_size}")


def get_transform(name: str) -> Transform:
    if name not in TRANSFORMS:
        raise ValueError(f"unknown feature transform {name!r}; known: {sorted(TRANSFORMS)}")
    return TRANSFORMS[name]


def feature_size(name: str, obs_size: int) -> int:
    """Length of the features of an observation of length ``obs_size``."""
    check_transform(name, obs_size)
    return _SIZES[name](obs_size)


def default_features(env_name: str) -> str:
    """The transform an environment trains with by default: ``maif-ego/1`` for MAIF."""
    return MAIF_EGO if env_name.startswith("maif") else IDENTITY
