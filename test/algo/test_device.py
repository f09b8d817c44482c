"""``train.device``: the device path is the CPU path where no GPU is lent (``auto`` resolves to
the CPU here and gives the bitwise same training), the networks and every tensor an update
builds live on the resolved device, checkpoints hold host arrays (loadable on any device), and
a device the machine lacks is refused naming the field. The CUDA path itself is unverified on
hardware (no GPU on the machines this is tested on)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import BatchedEnv
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.device import resolve_device, to_device, to_numpy
from sdhn_train.trainer import Trainer


def _short(name: str, num_envs: int, seed: int, **kw: object) -> BatchedEnv:
    return make_env(name, num_envs=num_envs, seed=seed, max_steps=12)  # rollouts cross resets


def _trainer(algo: str, device: str, root: Path) -> Trainer:
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.algo.name = "maif-tiny", 4, algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.epochs = 16, 2, 2
    cfg.eval.interval, cfg.log.tensorboard, cfg.log.progress = 0, False, False
    set_field(cfg, "train.device", device)
    validate(cfg)
    return Trainer(cfg, _short, run_dir=root)


@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
def test_auto_device_trains_exactly_as_the_cpu_path(algo: str, tmp_path: Path) -> None:
    states = {}
    for device in ("cpu", "auto"):
        tr = _trainer(algo, device, tmp_path / device)
        want = resolve_device(device)
        assert tr.device == want
        for module in (tr.learner.actor, tr.learner.critic):
            assert {p.device for p in module.parameters()} == {want}
        for _ in range(2):
            tr.train_iteration()
        assert tr.collector.actor_h.dtype == np.float32  # host arrays between iterations
        states[device] = tr.learner.state_dict()[0]
    assert states["cpu"].keys() == states["auto"].keys()
    for k, v in states["cpu"].items():
        assert isinstance(states["auto"][k], np.ndarray), k  # checkpoints: host arrays
        np.testing.assert_array_equal(states["auto"][k], v, err_msg=k)


def test_a_checkpoint_moves_between_device_settings(tmp_path: Path) -> None:
    """Written under one setting, loaded under another, the run continues as the writer's
    would (the checkpoint holds NumPy arrays, never device tensors)."""
    a = _trainer("sdhn", "cpu", tmp_path / "a")
    a.run_dir.mkdir(parents=True)
    a.train_iteration()
    path = a.save_checkpoint()
    a.train_iteration()  # before b exists: building a trainer seeds torch's global RNG
    want = a.learner.state_dict()[0]
    b = _trainer("sdhn", "auto", tmp_path / "b")
    b.load_checkpoint(path)
    b.train_iteration()
    got = b.learner.state_dict()[0]
    for k, v in want.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)


def test_devices_are_validated_naming_the_field() -> None:
    cfg = Config()
    set_field(cfg, "train.device", "tpu")
    with pytest.raises(ConfigError, match=r"train\.device.*allowed: cpu, cuda, auto"):
        validate(cfg)
    if not torch.cuda.is_available():
        set_field(cfg, "train.device", "cuda")
        with pytest.raises(ConfigError, match=r"train\.device.*no CUDA GPU"):
            validate(cfg)
    with pytest.raises(ValueError, match=r"train\.device"):
        resolve_device("gpu")


def test_host_device_round_trip() -> None:
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    t = to_device(a, torch.device("cpu"))
    back = to_numpy(t)
    np.testing.assert_array_equal(back, a)
    back[0, 0] = 99.0
    assert a[0, 0] == 0.0, "to_numpy hands back a copy the caller owns"
