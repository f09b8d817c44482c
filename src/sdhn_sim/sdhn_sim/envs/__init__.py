"""Environments of sdhn (pure NumPy; no ROS, no torch): MAIF, RWARE in NumPy and the
adapter of the real rware package.

Entry points: ``make_env(name, num_envs, seed, **overrides)``, ``env_names()``,
``make_single_env(name, seed)``. Every env follows ``api.BatchedEnv``.

Axis convention (everywhere): cell ``(x, y)``, x = column to the right, y = row downwards,
grids indexed ``[y, x]``; MAIF action ``up`` = y - 1, ``down`` = y + 1, ``left`` = x - 1,
``right`` = x + 1.
"""

from .api import BatchedEnv, EpisodeStats, StepResult
from .maif import MAIF_REWARDS, MaifEnv, MaifRewards, MaifWorld
from .maif_instances import MAIF_CONFIGS, MaifConfig, MaifInstances, load_instances
from .registry import env_names, make_env, make_single_env
from .render import render_grid, robot_colors
from .rware_batched import RwareBatchedEnv
from .rware_env import RwareEnv
from .single import SingleEnv, SingleStep

__all__ = [
    "MAIF_CONFIGS",
    "MAIF_REWARDS",
    "BatchedEnv",
    "EpisodeStats",
    "MaifConfig",
    "MaifEnv",
    "MaifInstances",
    "MaifRewards",
    "MaifWorld",
    "RwareBatchedEnv",
    "RwareEnv",
    "SingleEnv",
    "SingleStep",
    "StepResult",
    "env_names",
    "load_instances",
    "make_env",
    "make_single_env",
    "render_grid",
    "robot_colors",
]
