"""MAIF configurations and their fixed instance sets (maps x formations), pure NumPy.

Axis convention (used everywhere in ``sdhn_sim.envs``): a cell is ``(x, y)`` with ``x`` the column
(growing to the right) and ``y`` the row (growing downwards); grids are indexed ``grid[y, x]``.
Action ``up`` is ``y - 1``, ``down`` is ``y + 1``, ``left`` is ``x - 1``, ``right`` is ``x + 1``.

An instance set holds ``num_maps`` obstacle maps and ``num_formations`` formations per map;
instance id ``k`` is map ``k // num_formations``, formation ``k % num_formations``.
Sets for the shipped configurations live in ``sdhn_sim/data/<name>.npz`` (written by
``scripts/make_maif_instances.py``); the others are generated on demand by the same code.

Sets of a configuration with generator seed ``s`` (``instance_seed``), pairwise disjoint seeds:
``train`` (s, 10 maps x 10), ``heldout`` (s + 500,000, 10 x 10), ``large`` (s + 1,000,000,
100 x 10, to train on), ``heldout_large`` (s + 2,000,000, 200 x 5, evaluation only) and the
``procedural`` training stream (one map per instance, seeded ``[s + 3,000,000, k]``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sdhn_sim import data_files


@dataclass(frozen=True)
class MaifConfig:
    """One MAIF configuration: robots, grid size, formation square and the instance-set seed."""

    name: str
    num_robots: int
    size: int
    fs: int  # side of the start (top-left) and goal (bottom-right) squares
    obstacle_density: float = 0.1
    num_maps: int = 10
    num_formations: int = 10
    instance_seed: int = 0

    def __post_init__(self) -> None:
        if self.fs * self.fs < self.num_robots:
            raise ValueError(f"{self.name}: fs={self.fs} square has fewer cells than num_robots")
        if 2 * self.fs > self.size:
            raise ValueError(f"{self.name}: start and goal squares (fs={self.fs}) overlap")

    @property
    def num_instances(self) -> int:
        return self.num_maps * self.num_formations


def _cfg(name: str, n: int, size: int, fs: int, seed: int) -> MaifConfig:
    return MaifConfig(name=name, num_robots=n, size=size, fs=fs, instance_seed=seed)


FLEET_FORMATION_CELLS_PER_ROBOT = 5.6
"""Cells of formation square per robot in the fleet sizes (maif-30: 169 / 30, maif-40: 225 / 40)."""
FLEET_MAP_CELLS_PER_ROBOT = 9216 / 40
"""Map cells per robot in the fleet sizes: maif-40's 96 x 96 / 40 = 230.4 (so 207 free cells per
robot at 10 % obstacles); a larger fleet gets a larger map, not a denser one."""
FLEET_SIZE_STEP = 8


def fleet_config(num_robots: int, instance_seed: int | None = None) -> MaifConfig:
    """The MAIF configuration ``maif-<N>`` for a fleet of ``num_robots`` beyond the spec's
    sequence, keeping maif-40's densities: the formation square is the smallest odd side with
    at least 5.6 cells per robot, the map the smallest multiple of 8 with at least 230.4 cells
    per robot (obstacles stay at 10 %). maif-40 itself comes out of it unchanged (96, fs 15).
    The instance seed is ``1000 + N`` like the others' unless given."""
    n = int(num_robots)
    if n < 1:
        raise ValueError(f"num_robots must be an int >= 1, got {num_robots!r}")
    fs = math.ceil(math.sqrt(FLEET_FORMATION_CELLS_PER_ROBOT * n))
    fs += 1 - fs % 2
    side = math.ceil(math.sqrt(FLEET_MAP_CELLS_PER_ROBOT * n) / FLEET_SIZE_STEP) * FLEET_SIZE_STEP
    return _cfg(f"maif-{n}", n, max(side, 2 * fs), fs,
                1000 + n if instance_seed is None else int(instance_seed))


# maif-10/16/20 come from the spec. The sequence continues with fs += 2 and size += 16 per step
# (about 5-6 cells of formation square per robot): 30 robots -> 80x80, fs 13; 40 -> 96x96, fs 15.
# The fleet sizes (60, 100) come from ``fleet_config``, which keeps maif-40's densities.
MAIF_CONFIGS: dict[str, MaifConfig] = {
    c.name: c
    for c in (
        _cfg("maif-solo", 1, 12, 4, 1001),  # one robot alone on a maif-tiny-sized map (tests)
        _cfg("maif-tiny", 4, 12, 4, 1004),
        _cfg("maif-10", 10, 32, 7, 1010),
        _cfg("maif-16", 16, 48, 9, 1016),
        _cfg("maif-20", 20, 64, 11, 1020),
        _cfg("maif-30", 30, 80, 13, 1030),
        _cfg("maif-40", 40, 96, 15, 1040),
        fleet_config(60),
        fleet_config(100),
    )
}
SHIPPED = data_files.MAIF_SHIPPED
HELDOUT_SEED_OFFSET = 500_000
"""Held-out instances of a configuration: the same generator with ``instance_seed`` + this."""


LARGE_SEED_OFFSET = 1_000_000
LARGE_MAPS = 100
HELDOUT_LARGE_SEED_OFFSET = 2_000_000
HELDOUT_LARGE_MAPS = 200
HELDOUT_LARGE_FORMATIONS = 5
"""The large held-out set: 200 maps x 5 formations = 1,000 instances from seed + 2,000,000. No
training run ever sees it; it is what a policy's generalisation is measured on."""
VALIDATION_SEED_OFFSET = 4_000_000
"""The validation set: the large held-out set's shape (200 maps x 5 formations) from seed +
4,000,000. Deployment settings (the stall rule, sampling temperatures) are chosen on it, so the
large held-out set reports them without having been looked at while choosing."""
PROCEDURAL_SEED_OFFSET = 3_000_000
PROCEDURAL_MAPS = 1_000_000
"""The procedural training stream: map ``k`` (one formation each) is drawn from the generator
seeded ``[instance_seed + 3,000,000, k]``; a random draw from a million maps is a fresh map."""


def heldout_config(cfg: MaifConfig) -> MaifConfig:
    """The configuration of ``cfg``'s held-out instance set (maps a policy never trained on)."""
    return dataclasses.replace(cfg, instance_seed=cfg.instance_seed + HELDOUT_SEED_OFFSET)


def large_config(cfg: MaifConfig) -> MaifConfig:
    """A larger training set (100 maps x 10 formations, seed + 1,000,000): a policy trained on
    the 10 fixed maps learns those maps; on many maps it learns the task."""
    return dataclasses.replace(cfg, num_maps=LARGE_MAPS,
                               instance_seed=cfg.instance_seed + LARGE_SEED_OFFSET)


def heldout_large_config(cfg: MaifConfig) -> MaifConfig:
    """The configuration of ``cfg``'s large held-out set (1,000 instances on 200 maps)."""
    return dataclasses.replace(cfg, num_maps=HELDOUT_LARGE_MAPS,
                               num_formations=HELDOUT_LARGE_FORMATIONS,
                               instance_seed=cfg.instance_seed + HELDOUT_LARGE_SEED_OFFSET)


def validation_config(cfg: MaifConfig) -> MaifConfig:
    """The configuration of ``cfg``'s validation set (1,000 instances on 200 maps, for choosing
    deployment settings; neither trained nor reported on)."""
    return dataclasses.replace(heldout_large_config(cfg),
                               instance_seed=cfg.instance_seed + VALIDATION_SEED_OFFSET)


def procedural_config(cfg: MaifConfig) -> MaifConfig:
    """The configuration of ``cfg``'s procedural training stream (see ``ProceduralInstances``)."""
    return dataclasses.replace(cfg, num_maps=PROCEDURAL_MAPS, num_formations=1,
                               instance_seed=cfg.instance_seed + PROCEDURAL_SEED_OFFSET)


@dataclass(frozen=True)
class MaifInstances:
    """A fixed instance set. Coordinates are ``(x, y)`` (see the module docstring)."""

    config: MaifConfig
    obstacles: npt.NDArray[np.bool_]  # [M, size, size], indexed [map, y, x]
    starts: npt.NDArray[np.int64]  # [M, F, N, 2]
    goals: npt.NDArray[np.int64]  # [M, F, N, 2]

    @property
    def num_instances(self) -> int:
        return int(self.starts.shape[0] * self.starts.shape[1])

    @property
    def num_formations(self) -> int:
        return int(self.starts.shape[1])

    def instance(
        self, k: int
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """(obstacles [size, size], starts [N, 2], goals [N, 2]) of instance id ``k``."""
        m, f = divmod(int(k), self.starts.shape[1])
        return self.obstacles[m], self.starts[m, f], self.goals[m, f]


class ProceduralInstances:
    """Training maps drawn fresh from the generator: instance ``k`` is map ``k`` (one formation),
    generated on first use from its own seed ``[config.instance_seed, k]`` and kept in a small
    cache. Deterministic per ``k``, no fixed list: a run drawing instances at random from a
    million sees a new map almost every episode. Same interface as ``MaifInstances`` for
    ``MaifEnv`` (``config``, ``num_instances``, ``num_formations``, ``instance(k)``)."""

    def __init__(self, config: MaifConfig, cache_maps: int = 512) -> None:
        if config.num_formations != 1:
            raise ValueError(f"{config.name}: a procedural stream has one formation per map")
        self.config = config
        self._cached = functools.lru_cache(maxsize=cache_maps)(self._generate)

    @property
    def num_instances(self) -> int:
        return self.config.num_maps

    @property
    def num_formations(self) -> int:
        return 1

    def instance(
        self, k: int
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """(obstacles [size, size], starts [N, 2], goals [N, 2]) of instance id ``k``."""
        return self._cached(int(k))

    def _generate(
        self, k: int
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        if not 0 <= int(k) < self.config.num_maps:
            raise ValueError(f"instance id must be in [0, {self.config.num_maps}), got {k}")
        rng = np.random.default_rng([self.config.instance_seed, int(k)])
        while True:
            grid = _draw_map(self.config, rng)
            starts, goals = _draw_formation(self.config, rng)
            if _all_reachable(grid, starts, goals):
                for a in (grid, starts, goals):
                    a.setflags(write=False)  # shared through the cache
                return grid, starts, goals


def reachable_from(free: npt.NDArray[np.bool_], x: int, y: int) -> npt.NDArray[np.bool_]:
    """Cells reachable from ``(x, y)`` by 4-connected moves over ``free`` (BFS by dilation)."""
    reach = np.zeros_like(free)
    if not free[y, x]:
        return reach
    reach[y, x] = True
    while True:
        grown = reach.copy()
        grown[1:, :] |= reach[:-1, :]
        grown[:-1, :] |= reach[1:, :]
        grown[:, 1:] |= reach[:, :-1]
        grown[:, :-1] |= reach[:, 1:]
        grown &= free
        if np.array_equal(grown, reach):
            return reach
        reach = grown


def _draw_map(cfg: MaifConfig, rng: np.random.Generator) -> npt.NDArray[np.bool_]:
    s, fs = cfg.size, cfg.fs
    allowed = np.ones((s, s), dtype=bool)
    allowed[:fs, :fs] = False
    allowed[s - fs :, s - fs :] = False
    cells = np.flatnonzero(allowed)
    count = round(cfg.obstacle_density * s * s)
    chosen = rng.choice(cells, size=count, replace=False)
    obstacles = np.zeros(s * s, dtype=bool)
    obstacles[chosen] = True
    return obstacles.reshape(s, s)


def _draw_formation(
    cfg: MaifConfig, rng: np.random.Generator
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    fs, shift = cfg.fs, cfg.size - cfg.fs
    flat = rng.choice(fs * fs, size=cfg.num_robots, replace=False)
    starts = np.stack([flat % fs, flat // fs], axis=1).astype(np.int64)  # (x, y)
    return starts, starts + shift


def generate_instances(cfg: MaifConfig) -> MaifInstances:
    """Deterministic instance set of ``cfg`` from ``cfg.instance_seed``.

    A map is redrawn (together with its formations) until every goal of every formation is
    reachable from its start (4-connected BFS): the **fixed** item of the spec.
    """
    rng = np.random.default_rng(cfg.instance_seed)
    n, m_count, f_count = cfg.num_robots, cfg.num_maps, cfg.num_formations
    obstacles = np.zeros((m_count, cfg.size, cfg.size), dtype=bool)
    starts = np.zeros((m_count, f_count, n, 2), dtype=np.int64)
    goals = np.zeros_like(starts)
    for m in range(m_count):
        while True:
            grid = _draw_map(cfg, rng)
            forms = [_draw_formation(cfg, rng) for _ in range(f_count)]
            if all(_all_reachable(grid, st, gl) for st, gl in forms):
                break
        obstacles[m] = grid
        for f, (st, gl) in enumerate(forms):
            starts[m, f], goals[m, f] = st, gl
    return MaifInstances(cfg, obstacles, starts, goals)


def _all_reachable(
    obstacles: npt.NDArray[np.bool_], starts: npt.NDArray[np.int64], goals: npt.NDArray[np.int64]
) -> bool:
    free = ~obstacles
    cache: dict[int, npt.NDArray[np.bool_]] = {}
    labels = np.full(obstacles.shape, -1, dtype=np.int64)
    for (sx, sy), (gx, gy) in zip(starts.tolist(), goals.tolist(), strict=True):
        lab = int(labels[sy, sx])
        if lab < 0:
            lab = len(cache)
            cache[lab] = reachable_from(free, sx, sy)
            labels[cache[lab]] = lab
        if not cache[lab][gy, gx]:
            return False
    return True


def data_path(name: str) -> Path:
    """Where the instance set of ``name`` is shipped (or would be, see sdhn_sim.data_files)."""
    return data_files.maif_instance_file(name)


def save_instances(inst: MaifInstances, path: Path) -> None:
    c = inst.config
    np.savez_compressed(
        path,
        obstacles=np.packbits(inst.obstacles, axis=-1),
        starts=inst.starts.astype(np.int16),
        goals=inst.goals.astype(np.int16),
        meta=np.array(
            [c.num_robots, c.size, c.fs, c.num_maps, c.num_formations, c.instance_seed],
            dtype=np.int64,
        ),
        density=np.array(c.obstacle_density),
    )


def _load_file(cfg: MaifConfig, path: Path) -> MaifInstances:
    with np.load(path, allow_pickle=False) as z:
        meta = z["meta"].tolist()
        want = [cfg.num_robots, cfg.size, cfg.fs, cfg.num_maps, cfg.num_formations,
                cfg.instance_seed]
        if meta != want or float(z["density"]) != cfg.obstacle_density:
            raise ValueError(f"{path}: stored parameters {meta} do not match config {want}")
        obstacles = np.unpackbits(z["obstacles"], axis=-1, count=cfg.size).astype(bool)
        starts = z["starts"].astype(np.int64)
        goals = z["goals"].astype(np.int64)
    return MaifInstances(cfg, obstacles, starts, goals)


@functools.lru_cache(maxsize=16)
def load_instances(name_or_cfg: str | MaifConfig) -> MaifInstances:
    """The instance set of a configuration: from its data file if shipped, else generated."""
    if isinstance(name_or_cfg, str):
        if name_or_cfg not in MAIF_CONFIGS:
            raise ValueError(f"unknown MAIF config {name_or_cfg!r}; known: {sorted(MAIF_CONFIGS)}")
        cfg = MAIF_CONFIGS[name_or_cfg]
    else:
        cfg = name_or_cfg
    if MAIF_CONFIGS.get(cfg.name) == cfg and cfg.name in SHIPPED:
        # a shipped set must be there: a missing file is a packaging bug, not a cue to generate
        return _load_file(cfg, data_files.data_file(f"{cfg.name}.npz"))
    return generate_instances(cfg)
