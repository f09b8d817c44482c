"""NumPy-only rendering of a grid world to an RGB image (no matplotlib, no GUI)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FREE_RGB = (245, 245, 245)
OBSTACLE_RGB = (40, 40, 40)
GRID_RGB = (215, 215, 215)


def robot_colors(n: int) -> npt.NDArray[np.uint8]:
    """[n, 3] distinct colours by robot id (hues spread evenly, HSV s=0.85 v=0.9)."""
    h = np.arange(n, dtype=np.float64) / max(n, 1)
    s, v = 0.85, 0.9
    i = np.floor(h * 6).astype(np.int64) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    vv = np.full_like(h, v)
    pp = np.full_like(h, p)
    table = np.stack(
        [
            np.stack([vv, t, pp], 1),
            np.stack([q, vv, pp], 1),
            np.stack([pp, vv, t], 1),
            np.stack([pp, q, vv], 1),
            np.stack([t, pp, vv], 1),
            np.stack([vv, pp, q], 1),
        ]
    )  # [6, n, 3]
    rgb = table[i, np.arange(n)]
    return np.round(rgb * 255).astype(np.uint8)


def render_grid(
    obstacles: npt.ArrayLike,
    positions: npt.ArrayLike,
    goals: npt.ArrayLike | None = None,
    cell_px: int = 8,
) -> npt.NDArray[np.uint8]:
    """uint8 [H, W, 3] image: obstacles dark, goals as light squares, robots as filled squares.

    ``obstacles`` is [rows, cols] indexed [y, x]; ``positions``/``goals`` are [N, 2] (x, y).
    Robot ``i`` and its goal share colour ``robot_colors(N)[i]`` (goal lightened).
    """
    obs_grid = np.asarray(obstacles, dtype=bool)
    pos = np.asarray(positions, dtype=np.int64).reshape(-1, 2)
    c = int(cell_px)
    if c < 3:
        raise ValueError(f"cell_px must be >= 3, got {cell_px}")
    rows, cols = obs_grid.shape
    cells = np.empty((rows, cols, 3), dtype=np.uint8)
    cells[:] = FREE_RGB
    cells[obs_grid] = OBSTACLE_RGB
    img = np.repeat(np.repeat(cells, c, axis=0), c, axis=1)
    img[::c, :] = np.where(img[::c, :] == FREE_RGB, GRID_RGB, img[::c, :]).astype(np.uint8)
    img[:, ::c] = np.where(img[:, ::c] == FREE_RGB, GRID_RGB, img[:, ::c]).astype(np.uint8)
    colors = robot_colors(pos.shape[0])
    inner = np.arange(1, c)
    if goals is not None:
        gl = np.asarray(goals, dtype=np.int64).reshape(-1, 2)
        light = (colors.astype(np.int64) + 2 * 255) // 3
        yy = gl[:, 1, None, None] * c + inner[None, :, None]
        xx = gl[:, 0, None, None] * c + inner[None, None, :]
        img[yy, xx] = light[:, None, None, :].astype(np.uint8)
    m = max(1, c // 5)
    body = np.arange(m + 1, c - m)
    if body.size == 0:
        body = inner
    yy = pos[:, 1, None, None] * c + body[None, :, None]
    xx = pos[:, 0, None, None] * c + body[None, None, :]
    img[yy, xx] = colors[:, None, None, :]
    return img
