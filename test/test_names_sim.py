"""Each environment name has one source: the launcher, the simulator (its core config and its
node's parameter path) and the viz node accept exactly ``sdhn_sim.envs.registry.env_names()``, no
more and no fewer.

Same shape as the sdhn_train names test (an *acceptor* is ``name -> bool``, True = accepted), so
the two tables can be merged into one.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from sdhn_sim.envs.registry import env_names
from sdhn_sim.launch.supervisor import LaunchConfigError, load_config
from sdhn_sim.lockstep import SimConfig, SimConfigError
from sdhn_sim.ros.runner import ConfigError
from sdhn_sim.sim_node import PARAMETERS, sim_config
from sdhn_sim.viz.viz_node import _check_params as viz_check_params

ENVS = set(env_names())
ENV_DECOYS = {"maif-11", "maif", "MAIF-10", "maif-tiny ", "rware-4", "", "sdhn", "mappo"}

Acceptor = Callable[[str], bool]


def _raises(fn: Callable[[], object], *errors: type[Exception]) -> bool:
    """True if ``fn`` runs, False if it raises one of ``errors``."""
    try:
        fn()
    except errors:
        return False
    return True


def launcher_env(name: str) -> bool:
    return _raises(lambda: load_config(None, ["mode=train", f"env={name!r}"]), LaunchConfigError)


def sim_core_env(name: str) -> bool:
    return _raises(lambda: SimConfig(env=name).validate(), SimConfigError)


def sim_node_env(name: str) -> bool:
    """The node's path: declared defaults with ``env`` overridden -> the core's config."""
    params = {k: default for k, (default, _) in PARAMETERS.items()}
    return _raises(lambda: sim_config({**params, "env": name}).validate(), SimConfigError)


def viz_node_env(name: str) -> bool:
    if name == "":
        return False  # '' means "whatever the messages name" there, not an environment
    return _raises(lambda: viz_check_params("/sdhn", name, "127.0.0.1"), ConfigError)


ENV_ACCEPTORS: list[Acceptor] = [launcher_env, sim_core_env, sim_node_env, viz_node_env]


@pytest.mark.parametrize("accepts", ENV_ACCEPTORS, ids=lambda f: f.__name__)
def test_accepts_exactly_the_env_registry(accepts: Acceptor) -> None:
    wrongly_refused = sorted(n for n in ENVS if not accepts(n))
    wrongly_accepted = sorted(n for n in ENV_DECOYS if accepts(n))
    assert not wrongly_refused, f"{accepts.__name__} refuses registry envs {wrongly_refused}"
    assert not wrongly_accepted, f"{accepts.__name__} accepts non-envs {wrongly_accepted}"
