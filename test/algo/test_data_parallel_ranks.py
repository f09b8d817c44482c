"""``train.learner_processes``: K = 2 data-parallel ranks (real gloo processes on
localhost) give the K = 1 update on the same data, and a ``train`` run with them checkpoints and
resumes.

The exactness test feeds one fixed rollout of B = 4 environments: K = 1 updates on all of it,
rank r of K = 2 on environments 2r..2r+1. Minibatch m of K = 1 is made the union of the ranks'
minibatch m (what data parallelism computes), so the two differ only in float summation order.
SDHN runs with deterministic hyperedges: with sampled ones every rank draws its own noise."""

from __future__ import annotations

import json
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp
from safetensors.numpy import load_file

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import BatchedEnv
from sdhn_train.cli import main as train_main
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.data_parallel import Group, RankFailedError, end_rank
from sdhn_train.ranks import learner_ranks
from sdhn_train.rollout import Rollout
from sdhn_train.trainer import Trainer, rank_seed

B, HALF = 4, 2


def _short(name: str, num_envs: int, seed: int, **kw: object) -> BatchedEnv:
    return make_env(name, num_envs=num_envs, seed=seed, max_steps=12)  # rollouts cross resets


def _cfg(algo: str) -> Config:
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.algo.name = "maif-tiny", B, algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.epochs = 16, 2, 2
    cfg.eval.interval, cfg.log.tensorboard, cfg.log.progress = 0, False, False
    if algo == "sdhn":
        set_field(cfg, "sdhn.stochastic_hyperedges", "false")
    return cfg


def _save_rollout(r: Rollout, path: Path) -> None:
    arrays = {k: v for k, v in vars(r).items() if v is not None}
    np.savez(path, **arrays)


def _slice(path: Path, envs: slice) -> Rollout:
    """Environments ``envs`` of the stored rollout (env axis 1; actor_h0's is 0)."""
    with np.load(path) as z:
        a = {k: z[k] for k in z.files}
    out = {k: (v[envs] if k == "actor_h0" else v[:, envs]) for k, v in a.items()}
    return Rollout(**out)


def _rank(rank: int, algo: str, store: str, rollout: str, out: str) -> None:
    """One learner process of the K = 2 update (spawned; module-level so it pickles)."""
    group = Group.join(rank, 2, store)
    code = 1
    try:
        tr = Trainer(_cfg(algo), _short, run_dir=Path(out).parent)  # same seed: same init
        tr.learner.group = group  # type: ignore[attr-defined]
        tr.learner.update(_slice(Path(rollout), slice(rank * HALF, (rank + 1) * HALF)))
        if rank == 0:
            np.savez(out, **tr.learner.state_dict()[0])
        code = 0
    except BaseException:
        traceback.print_exc()  # os._exit below would swallow it
    finally:
        group.close()
        end_rank(code)  # as the trainer's ranks end


@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
def test_two_learner_processes_give_the_one_process_update(algo: str, tmp_path: Path) -> None:
    one = Trainer(_cfg(algo), _short, run_dir=tmp_path)
    rollout, _ = one.collector.collect(one.critic_h)
    assert rollout.done.any(), "the rollout must cross episode ends"
    _save_rollout(rollout, tmp_path / "rollout.npz")

    # K = 1 on the same minibatches as the ranks: each rank permutes its own 2 envs with the
    # same generator (seeded train.seed), rank 1's are envs 2..3.
    rng = np.random.default_rng(one.cfg.train.seed)

    def union(b: int) -> list[torch.Tensor]:
        perm = rng.permutation(HALF)
        return [torch.tensor([p, HALF + p]) for p in perm]

    one.learner.minibatch_envs = union  # type: ignore[attr-defined]
    one.learner.update(_slice(tmp_path / "rollout.npz", slice(0, B)))
    want = one.learner.state_dict()[0]

    ctx = mp.get_context("spawn")
    args = (algo, str(tmp_path / "store"), str(tmp_path / "rollout.npz"),
            str(tmp_path / "rank0.npz"))
    procs = [ctx.Process(target=_rank, args=(r, *args)) for r in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    assert [p.exitcode for p in procs] == [0, 0], "a data-parallel rank failed"
    with np.load(tmp_path / "rank0.npz") as z:
        got = {k: z[k] for k in z.files}
    assert want.keys() == got.keys()
    before = _initial(algo, tmp_path)
    changed = [k for k in before if not np.array_equal(want[k], before[k])]
    assert changed, "the update must change the parameters"
    for k, v in want.items():
        np.testing.assert_allclose(got[k], v, rtol=1e-5, atol=1e-5, err_msg=k)


def _initial(algo: str, root: Path) -> dict[str, Any]:
    return Trainer(_cfg(algo), _short, run_dir=root).learner.state_dict()[0]


@pytest.mark.parametrize(("sets", "field"), [
    ({"train.learner_processes": "0"}, "train.learner_processes"),
    ({"train.learner_processes": "3"}, "train.learner_processes"),  # B = 4
    ({"train.learner_processes": "2", "ppo.num_minibatches": "4"}, "ppo.num_minibatches"),
    ({"train.learner_processes": "2", "ppo.concurrent_actor_critic": "true"},
     "ppo.concurrent_actor_critic"),
    ({"train.learner_processes": "2", "algo.name": "qmix"}, "train.learner_processes"),
])
def test_learner_processes_config_is_checked(sets: dict[str, str], field: str) -> None:
    cfg = _cfg("mappo")
    for k, v in sets.items():
        set_field(cfg, k, v)
    with pytest.raises(ConfigError, match=field):
        validate(cfg)


def _train(root: Path, name: str, *extra: str) -> int:
    return train_main([
        "--env", "maif-tiny", "--algo", "mappo", "--set", "env.num_envs=4",
        "--set", "ppo.rollout_len=16", "--set", "ppo.num_minibatches=2",
        "--set", "eval.interval=0", "--set", "log.progress=false",
        "--set", "log.tensorboard=false", "--set", "train.learner_processes=2",
        "--set", f"log.root={root}", "--set", f"log.run_name={name}", *extra])


def test_train_with_two_learner_processes_checkpoints_and_resumes(tmp_path: Path) -> None:
    """Stopping at a checkpoint and resuming gives the uninterrupted run's actor: every rank's
    environments, carries and RNG come back, not only rank 0's."""
    assert _train(tmp_path, "whole", "--set", "train.total_steps=128") == 0
    assert _train(tmp_path, "split", "--set", "train.total_steps=64") == 0
    run = tmp_path / "split"
    ckpts = sorted((run / "checkpoints").glob("*.json"))
    assert [c.stem for c in ckpts] == ["step_000000000064"], ckpts
    meta = json.loads(ckpts[-1].read_text())
    assert "rank1.env_values" in meta, "rank 1's shard is missing from the checkpoint"
    assert train_main(["--resume", str(run), "--set", "train.total_steps=128"]) == 0

    summary = json.loads((run / "summary.json").read_text())
    assert summary["global_step"] == 128, summary
    want = load_file(str(tmp_path / "whole" / "actor.safetensors"))
    got = load_file(str(run / "actor.safetensors"))
    assert want.keys() == got.keys()
    for k, v in want.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)


def _broken_in_rank_1(name: str, num_envs: int, seed: int, **kw: object) -> BatchedEnv:
    if seed == rank_seed(_cfg("mappo").train.seed, 1):
        raise ValueError("no environments in rank 1")
    return _short(name, num_envs, seed)


def test_a_failed_learner_process_ends_the_run_with_one_error(tmp_path: Path) -> None:
    cfg = _cfg("mappo")
    cfg.train.learner_processes = 2
    expect = "data-parallel rank 1 failed: ValueError: no environments in rank 1"
    with (pytest.raises(RankFailedError, match=expect),
          learner_ranks(cfg, tmp_path, env_factory=_broken_in_rank_1) as group):
        Trainer(cfg, _short, run_dir=tmp_path, group=group)
