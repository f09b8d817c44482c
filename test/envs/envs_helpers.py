"""Shared helpers of the env tests: hand-built MAIF scenarios."""

from __future__ import annotations

import numpy as np

from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_instances import MaifConfig, MaifInstances


def scenario(
    starts: list[tuple[int, int]],
    goals: list[tuple[int, int]],
    obstacles: list[tuple[int, int]] = (),  # type: ignore[assignment]
    size: int = 8,
    **kw: object,
) -> MaifEnv:
    """A one-instance MAIF env on a ``size`` grid; cells are (x, y). Reset already done."""
    n = len(starts)
    grid = np.zeros((1, size, size), dtype=bool)
    for x, y in obstacles:
        grid[0, y, x] = True
    fs = max(2, int(np.ceil(np.sqrt(n))))
    cfg = MaifConfig(name="test", num_robots=n, size=size, fs=fs, num_maps=1, num_formations=1)
    inst = MaifInstances(
        cfg,
        grid,
        np.array(starts, dtype=np.int64).reshape(1, 1, n, 2),
        np.array(goals, dtype=np.int64).reshape(1, 1, n, 2),
    )
    env = MaifEnv(inst, num_envs=1, seed=0, **kw)  # type: ignore[arg-type]
    env.reset()
    return env

