"""Named environments: ``make_env(name, num_envs, seed, **overrides) -> BatchedEnv``.

MAIF: ``maif-solo`` (1 robot, 12x12, fs 4), ``maif-tiny`` (4 robots, 12x12, fs 4),
``maif-10`` (32, fs 7), ``maif-16`` (48, fs 9),
``maif-20`` (64, fs 11), ``maif-30`` (80, fs 13), ``maif-40`` (96, fs 15);
the fleet sizes ``maif-60`` (120, fs 19), ``maif-100`` (152, fs 25) from ``fleet_config``.
Overrides: ``max_steps`` (int >= 1), ``instance_ids`` (list of ints in [0, 100)),
``instance_order`` ("random" | "round_robin"), ``reward`` ("corrected" (default) | "reference"),
``instance_set`` ("train" (default): the 100 fixed instances | "heldout": 100 instances drawn
with another generator seed, for evaluation on maps never trained on | "large": 1000 instances
(100 maps) from a third seed, to train on many maps | "heldout_large": 1000 instances (200 maps)
from a fourth seed, the large held-out set no training run sees | "validation": the same size
from a sixth seed, where deployment settings are chosen | "procedural": a fresh map per
instance from a fifth seed, a training stream with no fixed list).

RWARE: ``rware-3``, ``rware-6``, ``rware-9`` = rware's ``rware-small-{N}ag-v2``;
``rware-tiny-2ag``, ``rware-tiny-4ag`` = rware's ``rware-tiny-{N}ag-v2`` (the tasks with published
MAPPO figures). Overrides: ``max_steps``, ``size`` ("tiny" | "small" | "medium" | "large"),
``difficulty`` ("easy" | "normal" | "hard"), ``backend`` ("batched" (default): the NumPy
``RwareBatchedEnv``, equal to rware step for step | "rware": B real ``rware`` warehouses, the
reference, whose ``Warehouse`` objects the centralised scripted policy reads).

Adding an environment is one module implementing ``BatchedEnv`` plus one ``Family`` line in
``FAMILIES`` (see docs/adding-an-environment.md); every tool that takes an env name (trainer,
launcher, simulator, viz, experiment suites) reads the names from here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .api import BatchedEnv
from .maif import MaifEnv
from .maif_instances import (
    MAIF_CONFIGS,
    MaifInstances,
    ProceduralInstances,
    heldout_config,
    heldout_large_config,
    large_config,
    load_instances,
    procedural_config,
    validation_config,
)
from .rware_batched import RwareBatchedEnv
from .rware_env import RwareEnv
from .single import SingleEnv

MAIF_OVERRIDES = ("max_steps", "instance_ids", "instance_order", "reward", "instance_set")
INSTANCE_SETS = ("train", "heldout", "large", "heldout_large", "validation", "procedural")
TRAINING_SETS = ("train", "large", "procedural")
"""The sets a training run may draw from; the held-out sets are for evaluation only."""
RWARE_OVERRIDES = ("max_steps", "size", "difficulty", "backend")
RWARE_TASKS = {"rware-3": 3, "rware-6": 6, "rware-9": 9, "rware-tiny-2ag": 2, "rware-tiny-4ag": 4}
RWARE_TASK_SIZE = {"rware-tiny-2ag": "tiny", "rware-tiny-4ag": "tiny"}  # others: "small"
RWARE_BACKENDS = ("batched", "rware")


@dataclass(frozen=True)
class Family:
    """Named environments built by one constructor: name -> team size, and the overrides the
    constructor takes (anything else is refused before it is called)."""

    teams: dict[str, int]
    overrides: tuple[str, ...]
    make: Callable[..., BatchedEnv]  # (name, num_envs, seed, **overrides) -> env


def _make_maif(name: str, num_envs: int, seed: int, **overrides: Any) -> BatchedEnv:
    which = overrides.pop("instance_set", "train")
    return MaifEnv(instance_set(name, which), num_envs=num_envs, seed=seed, name=name,
                   **overrides)


def instance_set(name: str, which: str) -> MaifInstances | ProceduralInstances:
    """The instances of MAIF configuration ``name``'s set ``which`` (one of INSTANCE_SETS)."""
    if which not in INSTANCE_SETS:
        raise ValueError(f"instance_set must be one of {list(INSTANCE_SETS)}, got {which!r}")
    cfg = MAIF_CONFIGS[name]
    if which == "procedural":
        return ProceduralInstances(procedural_config(cfg))
    cfg = {"train": cfg, "heldout": heldout_config(cfg), "large": large_config(cfg),
           "heldout_large": heldout_large_config(cfg), "validation": validation_config(cfg)}[which]
    return load_instances(cfg)


def rware_task_size(name: str) -> str:
    """The rware warehouse size of an RWARE task name."""
    return RWARE_TASK_SIZE.get(name, "small")


def _make_rware(name: str, num_envs: int, seed: int, **overrides: Any) -> BatchedEnv:
    backend = overrides.pop("backend", "batched")
    if backend not in RWARE_BACKENDS:
        raise ValueError(f"backend must be one of {list(RWARE_BACKENDS)}, got {backend!r}")
    overrides.setdefault("size", rware_task_size(name))
    cls = RwareBatchedEnv if backend == "batched" else RwareEnv
    return cls(RWARE_TASKS[name], num_envs=num_envs, seed=seed, name=name, **overrides)


FAMILIES: tuple[Family, ...] = (
    Family({k: c.num_robots for k, c in MAIF_CONFIGS.items()}, MAIF_OVERRIDES, _make_maif),
    Family(dict(RWARE_TASKS), RWARE_OVERRIDES, _make_rware),
)


def env_names() -> list[str]:
    """Every name ``make_env`` accepts."""
    return [name for family in FAMILIES for name in family.teams]


def _family(name: str) -> Family:
    for family in FAMILIES:
        if name in family.teams:
            return family
    raise ValueError(f"unknown environment {name!r}; known: {env_names()}")


def team_size(name: str) -> int:
    """Robots of the named environment (without building it)."""
    return int(_family(name).teams[name])


def make_env(name: str, num_envs: int = 1, seed: int = 0, **overrides: Any) -> BatchedEnv:
    """A batched environment by name (see ``env_names()``)."""
    family = _family(name)
    for key in overrides:
        if key not in family.overrides:
            raise ValueError(f"{name}: unknown override {key!r}; allowed: {list(family.overrides)}")
    return family.make(name, num_envs, seed, **overrides)


def make_single_env(name: str, seed: int = 0, **overrides: Any) -> SingleEnv:
    """A single-environment view (for the simulator node and Gymnasium-style loops)."""
    return SingleEnv(make_env(name, num_envs=1, seed=seed, **overrides))
