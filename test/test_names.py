"""Each name has one source: every place that takes an environment or algorithm name accepts
exactly the names of the env registry (``sdhn_sim.envs.registry.env_names``) and of the algorithm
registry (``sdhn_train.algorithms.registry.ALGO_NAMES``), no more and no fewer.

An *acceptor* is ``name -> bool`` (True = accepted). To cover another place that takes names, add
one function and list it in ENV_ACCEPTORS / ALGO_ACCEPTORS.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from pathlib import Path

import pytest

from sdhn_base.ros.runner import ConfigError as NodeConfigError
from sdhn_bringup.launch_load import LaunchConfigError, load_config
from sdhn_experiments.experiments import ExperimentError, load_suite
from sdhn_experiments.figures import method_order, task_order
from sdhn_sim.envs.registry import env_names
from sdhn_sim.lockstep import SimConfig, SimConfigError
from sdhn_sim.poses import target_reader
from sdhn_sim.sim_node import PARAMETERS, sim_config
from sdhn_sim.viz.viz_node import _check_params as viz_check_params
from sdhn_train import cli
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.config import Config, ConfigError, validate
from sdhn_train.trainer_node import check_params, default_params

ENVS = set(env_names())
ALGOS = set(ALGO_NAMES)
# Near misses and each other's names: none of these may be accepted as the other kind.
ENV_DECOYS = {"maif-11", "maif", "MAIF-10", "maif-tiny ", "rware-4", "", *ALGOS}
ALGO_DECOYS = {"SDHN", "ppo", "qmix2", "hgcn-mix", "sdhn_wo_lsk", "", *ENVS}

Acceptor = Callable[[str], bool]


def _raises(fn: Callable[[], object], *errors: type[Exception]) -> bool:
    """True if ``fn`` runs, False if it raises one of ``errors``."""
    try:
        fn()
    except errors:
        return False
    return True


def config_env(name: str) -> bool:
    cfg = Config()
    cfg.env.name = name
    return _raises(lambda: validate(cfg), ConfigError)


def config_algo(name: str) -> bool:
    cfg = Config()
    cfg.algo.name = name
    return _raises(lambda: validate(cfg), ConfigError)


def _cli(*argv: str) -> bool:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([*argv, "--print-config"])
    assert code in (0, 2), f"train {argv}: exit {code}: {err.getvalue()}"
    return code == 0


def cli_env(name: str) -> bool:
    return _cli("--env", name)


def cli_algo(name: str) -> bool:
    return _cli("--algo", name)


def node_env(name: str) -> bool:
    return _raises(lambda: check_params(default_params(env=name)), NodeConfigError)


def node_algo(name: str) -> bool:
    return _raises(lambda: check_params(default_params(algo=name)), NodeConfigError)


def _suite(tmp: Path, task: str, algo: str) -> bool:
    suite = tmp / f"suite-{abs(hash((task, algo)))}.yaml"
    suite.write_text(f"name: names\nmethods: {{m: {{algo: '{algo}'}}}}\n"
                     f"tasks: {{'{task}': {{}}}}\nbudgets: {{quick: {{}}}}\n")
    return _raises(lambda: load_suite(suite, "quick"), ExperimentError)


def figures_env(name: str) -> bool:
    return name in task_order()


def figures_algo(name: str) -> bool:
    return name in method_order() and name not in ("sdhn_wo_lsk", "sdhn_wo_shr")


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
    return _raises(lambda: viz_check_params("/sdhn", name, "127.0.0.1"), NodeConfigError)


def actor_target_env(name: str) -> bool:
    """The actor's ``env`` parameter (for its target pose): the node refuses a name without a
    target reader."""
    return target_reader(name) is not None


ENV_ACCEPTORS: dict[str, Acceptor] = {
    "trainer config": config_env, "train CLI": cli_env, "trainer node": node_env,
    "figures": figures_env, "launcher": launcher_env, "sim core": sim_core_env,
    "sim node": sim_node_env, "viz node": viz_node_env, "actor target pose": actor_target_env,
}
ALGO_ACCEPTORS: dict[str, Acceptor] = {
    "trainer config": config_algo, "train CLI": cli_algo, "trainer node": node_algo,
    "figures": figures_algo,
}


@pytest.mark.parametrize("where", sorted(ENV_ACCEPTORS))
def test_env_names_are_exactly_the_registrys(where: str) -> None:
    accept = ENV_ACCEPTORS[where]
    accepted = {n for n in ENVS | ENV_DECOYS if accept(n)}
    assert accepted == ENVS, (f"{where}: missing {sorted(ENVS - accepted)}, "
                              f"extra {sorted(accepted - ENVS)}")


@pytest.mark.parametrize("where", sorted(ALGO_ACCEPTORS))
def test_algo_names_are_exactly_the_registrys(where: str) -> None:
    accept = ALGO_ACCEPTORS[where]
    accepted = {n for n in ALGOS | ALGO_DECOYS if accept(n)}
    assert accepted == ALGOS, (f"{where}: missing {sorted(ALGOS - accepted)}, "
                               f"extra {sorted(accepted - ALGOS)}")


def test_experiment_suites_take_exactly_the_registrys_names(tmp_path: Path) -> None:
    tasks = {n for n in ENVS | ENV_DECOYS if _suite(tmp_path, n, "sdhn")}
    algos = {n for n in ALGOS | ALGO_DECOYS if _suite(tmp_path, "maif-tiny", n)}
    assert tasks == ENVS, f"suite tasks: missing {ENVS - tasks}, extra {tasks - ENVS}"
    assert algos == ALGOS, f"suite methods: missing {ALGOS - algos}, extra {algos - ALGOS}"


def test_the_registries_hold_the_papers_names() -> None:
    """A positive control: the lists compared above are not empty or truncated."""
    assert {"maif-tiny", "maif-10", "maif-30", "maif-40", "rware-3"} <= ENVS
    assert {"sdhn", "mappo", "qmix", "dicg", "hgcn_mix"} == ALGOS
