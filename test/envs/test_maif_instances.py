"""MAIF instance sets: shipped files, reachability (the fixed item), formation geometry."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from sdhn_sim.envs import env_names, make_env
from sdhn_sim.envs.maif_instances import (
    FLEET_FORMATION_CELLS_PER_ROBOT,
    FLEET_MAP_CELLS_PER_ROBOT,
    MAIF_CONFIGS,
    SHIPPED,
    MaifConfig,
    data_path,
    fleet_config,
    generate_instances,
    load_instances,
    reachable_from,
)


def bfs(free: np.ndarray, start: tuple[int, int]) -> set[tuple[int, int]]:
    """Independent 4-connected BFS over (x, y) cells."""
    size = free.shape[0]
    seen, todo = {start}, deque([start])
    while todo:
        x, y = todo.popleft()
        for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if 0 <= nx < size and 0 <= ny < size and free[ny, nx] and (nx, ny) not in seen:
                seen.add((nx, ny))
                todo.append((nx, ny))
    return seen


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_sets_are_valid(name):
    path = data_path(name)
    assert path.exists(), f"{path} missing: run scripts/make_maif_instances.py"
    inst = load_instances(name)
    cfg = inst.config
    n, s, fs = cfg.num_robots, cfg.size, cfg.fs
    assert inst.obstacles.shape == (10, s, s) and inst.starts.shape == (10, 10, n, 2)
    for m in range(10):
        grid = inst.obstacles[m]
        assert grid.sum() == round(0.1 * s * s), "obstacle density is 10 % of all cells"
        assert not grid[:fs, :fs].any() and not grid[s - fs :, s - fs :].any()
        reach = bfs(~grid, tuple(inst.starts[m, 0, 0]))
        for f in range(10):
            st, gl = inst.starts[m, f], inst.goals[m, f]
            assert len({tuple(p) for p in st.tolist()}) == n, "starts must be distinct"
            assert (st >= 0).all() and (st < fs).all(), "starts inside the start square"
            np.testing.assert_array_equal(gl, st + (s - fs), err_msg="goal = start translated")
            for p, g in zip(st.tolist(), gl.tolist(), strict=True):
                assert tuple(p) in reach and tuple(g) in reach, f"goal {g} unreachable from {p}"


@pytest.mark.parametrize("name", ["maif-tiny", "maif-10"])
def test_shipped_files_equal_generation(name):
    cfg = MAIF_CONFIGS[name]
    stored, fresh = load_instances(name), generate_instances(cfg)
    for field in ("obstacles", "starts", "goals"):
        np.testing.assert_array_equal(getattr(stored, field), getattr(fresh, field))


def test_unreachable_maps_are_redrawn():
    # dense obstacles make many raw maps cut the start square off from the goal square
    cfg = MaifConfig("dense", num_robots=4, size=10, fs=3, obstacle_density=0.45,
                     num_maps=6, num_formations=3, instance_seed=7)
    inst = generate_instances(cfg)
    for m in range(cfg.num_maps):
        reach = bfs(~inst.obstacles[m], (0, 0))
        for g in inst.goals[m].reshape(-1, 2).tolist():
            assert tuple(g) in reach


def test_reachable_from_detects_a_wall():
    free = np.ones((6, 6), dtype=bool)
    free[:, 3] = False  # a full wall at x = 3
    r = reachable_from(free, 0, 0)
    assert r[5, 2] and not r[0, 4] and not r[:, 3].any()
    assert {(x, y) for y, x in zip(*np.nonzero(r), strict=True)} == bfs(free, (0, 0))


def test_large_configs_generate_on_demand():
    for name, (n, s, fs) in {"maif-30": (30, 80, 13), "maif-40": (40, 96, 15)}.items():
        cfg = MAIF_CONFIGS[name]
        assert (cfg.num_robots, cfg.size, cfg.fs) == (n, s, fs)
        assert not data_path(name).exists()
    inst = load_instances("maif-30")
    assert inst.starts.shape == (10, 10, 30, 2)


def test_fleet_generator_keeps_maif40_densities_and_is_registered():
    """maif-60/100 come from fleet_config, which reproduces maif-40 and keeps its formation
    cells and map cells per robot for any N; the sets are generated, never shipped."""
    assert fleet_config(40) == MAIF_CONFIGS["maif-40"]
    for n in (60, 100, 137):
        cfg = fleet_config(n)
        assert cfg.fs % 2 == 1 and cfg.fs**2 >= FLEET_FORMATION_CELLS_PER_ROBOT * n
        assert (cfg.fs - 2) ** 2 < FLEET_FORMATION_CELLS_PER_ROBOT * n, "smallest such square"
        assert cfg.size**2 >= FLEET_MAP_CELLS_PER_ROBOT * n
        assert (cfg.size - 8) ** 2 < FLEET_MAP_CELLS_PER_ROBOT * n, "smallest such map"
    for name, n in (("maif-60", 60), ("maif-100", 100)):
        assert MAIF_CONFIGS[name] == fleet_config(n) and name in env_names()
        assert not data_path(name).exists()
    env = make_env("maif-100", num_envs=1, seed=0, instance_set="heldout")
    assert (env.num_robots, env.obs_size) == (100, 57), "egocentric: same observation size"
    with pytest.raises(ValueError, match="num_robots"):
        fleet_config(0)


def test_bad_config_rejected():
    with pytest.raises(ValueError, match="fs"):
        MaifConfig("x", num_robots=10, size=8, fs=3)
    with pytest.raises(ValueError, match="known"):
        load_instances("maif-7")
