"""Every speed option of the trainer that should not change the arithmetic gives the same
update as the straightforward path: whole training iterations (rollout + PPO update) crossing
episode ends, with and without the option, compared parameter by parameter (optimiser state
included)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import BatchedEnv
from sdhn_train.config import Config, set_field
from sdhn_train.trainer import Trainer


def _short(name: str, num_envs: int, seed: int, **kw: object) -> BatchedEnv:
    return make_env(name, num_envs=num_envs, seed=seed, max_steps=12)  # rollouts cross resets


def _state(algo: str, sets: dict[str, str], root: Path, iterations: int = 2
           ) -> dict[str, np.ndarray]:
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.algo.name = "maif-tiny", 4, algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.epochs = 16, 2, 2
    cfg.eval.interval, cfg.log.tensorboard, cfg.log.progress = 0, False, False
    for k, v in sets.items():
        set_field(cfg, k, v)
    tr = Trainer(cfg, _short, run_dir=root)
    for _ in range(iterations):
        tr.train_iteration()
    return tr.learner.state_dict()[0]


# (option, straightforward value, fast value, tolerance: 0 = bitwise)
OPTIONS = [
    ("ppo.fused_gru", "false", "true", 1e-5),
    ("ppo.concurrent_actor_critic", "false", "true", 0.0),
    # process-wide and sticky once set (an earlier Trainer in this process may have set it), so
    # this pair checks the option runs and changes nothing; test_retain_freed_memory_applies
    # checks that it takes effect
    ("train.retain_freed_memory", "false", "true", 0.0),
]


@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
@pytest.mark.parametrize("case", OPTIONS, ids=[o[0] for o in OPTIONS])
def test_speed_option_gives_the_straightforward_update(
        algo: str, case: tuple[str, str, str, float], tmp_path: Path) -> None:
    option, plain, fast, tol = case
    want = _state(algo, {option: plain}, tmp_path / "plain")
    got = _state(algo, {option: fast}, tmp_path / "fast")
    assert want.keys() == got.keys()
    for k, v in want.items():
        if tol:
            np.testing.assert_allclose(got[k], v, atol=tol, rtol=tol, err_msg=k)
        else:
            np.testing.assert_array_equal(got[k], v, err_msg=k)


def test_retain_freed_memory_applies_on_glibc_only() -> None:
    """On glibc (every machine this trains on) all three mallopt calls are accepted; elsewhere
    the call changes nothing and says so."""
    import platform

    from sdhn_train.runs import retain_freed_memory

    glibc = platform.libc_ver()[0] == "glibc"
    assert retain_freed_memory() is glibc, f"libc {platform.libc_ver()}"
