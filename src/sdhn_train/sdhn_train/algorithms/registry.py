"""The one list of algorithms. Everything that names an algorithm (the config, the CLI, the ROS
trainer node, the experiment runner, the figures) reads ``ALGO_NAMES`` or ``get_algorithm``.

    algo = get_algorithm("sdhn")                          # ConfigError for unknown names
    learner = algo.build_learner(cfg, EnvInfo.of(env), rng)

Adding an algorithm = one module under ``sdhn_train/algorithms/`` + one entry below
(docs/adding-an-algorithm.md).
"""

from __future__ import annotations

from sdhn_train.algorithms.base import Algorithm
from sdhn_train.algorithms.dicg import DICG
from sdhn_train.algorithms.hgcn_mix import HGCNMIX
from sdhn_train.algorithms.mappo import MAPPO
from sdhn_train.algorithms.qmix import QMIX
from sdhn_train.algorithms.sdhn import SDHN
from sdhn_train.sections import ConfigError

ALGORITHMS: tuple[Algorithm, ...] = (SDHN(), MAPPO(), QMIX(), DICG(), HGCNMIX())
ALGO_NAMES: tuple[str, ...] = tuple(a.name for a in ALGORITHMS)


def get_algorithm(name: str) -> Algorithm:
    for algo in ALGORITHMS:
        if algo.name == name:
            return algo
    raise ConfigError(f"algo.name = {name!r} is invalid; allowed: {', '.join(ALGO_NAMES)}")
