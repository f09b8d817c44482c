"""Warm start across team sizes for an actor that reads a one-hot robot id: the robots both
teams have act exactly as the trained actor made them act, a new robot starts as the mean of the
trained ids, and an actor that does not fit is still a config error."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.actor_torch import Actor
from sdhn_policy.team_size import input_tensor_name
from sdhn_policy.weights import ActorSpec, save_actor_file
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.warm_start import load_actor_into

SPECS = [
    ActorSpec(obs_size=9, num_actions=5, hidden_sizes=(16,), gru_hidden=8, use_robot_id=True,
              num_robots=2),
    ActorSpec(obs_size=9, num_actions=5, hidden_sizes=(), gru_hidden=8, use_robot_id=True,
              num_robots=2),
    ActorSpec(obs_size=9, num_actions=5, hidden_sizes=(), gru_hidden=0, use_robot_id=True,
              num_robots=2),
]


def _trained(spec: ActorSpec, path: Path) -> ActorRuntime:
    torch.manual_seed(0)
    actor = Actor(spec)
    with torch.no_grad():  # every weight away from its init, ids included
        for t in actor.tensors().values():
            t.add_(torch.randn_like(t))
    save_actor_file(path, actor.export(3))
    return ActorRuntime.from_file(path)


@pytest.mark.parametrize("spec", SPECS, ids=["mlp_gru", "gru_only", "linear"])
def test_two_robot_actor_warm_starts_a_three_robot_team(spec: ActorSpec, tmp_path: Path) -> None:
    src = _trained(spec, tmp_path / "two.safetensors")
    big = Actor(dataclasses.replace(spec, num_robots=3))
    assert load_actor_into(big, tmp_path / "two.safetensors") == 3
    rt = ActorRuntime.from_weights(big.export(1))
    obs = np.random.default_rng(1).normal(size=(2, 9)).astype(np.float32)
    ids = np.array([0, 1])
    logits_src = src.step(obs, src.initial_state(2), robot_id=ids)[0]
    logits_big = rt.step(obs, rt.initial_state(2), robot_id=ids)[0]
    np.testing.assert_allclose(logits_big, logits_src, rtol=1e-5, atol=1e-6)
    w = big.tensors()[input_tensor_name(big.spec)].detach().numpy()
    np.testing.assert_allclose(w[:, 11], w[:, 9:11].mean(axis=1), rtol=1e-6, atol=1e-7)


def test_three_robot_actor_warm_starts_a_two_robot_team(tmp_path: Path) -> None:
    spec = dataclasses.replace(SPECS[0], num_robots=3)
    src = _trained(spec, tmp_path / "three.safetensors")
    small = Actor(SPECS[0])
    load_actor_into(small, tmp_path / "three.safetensors")
    rt = ActorRuntime.from_weights(small.export(1))
    obs = np.random.default_rng(2).normal(size=(2, 9)).astype(np.float32)
    ids = np.array([0, 1])
    np.testing.assert_allclose(rt.step(obs, rt.initial_state(2), robot_id=ids)[0],
                               src.step(obs, src.initial_state(2), robot_id=ids)[0],
                               rtol=1e-5, atol=1e-6)


def test_an_actor_of_another_shape_is_still_refused(tmp_path: Path) -> None:
    _trained(SPECS[0], tmp_path / "two.safetensors")
    other = Actor(dataclasses.replace(SPECS[0], num_robots=3, gru_hidden=16))
    with pytest.raises(ConfigError, match="differs"):
        load_actor_into(other, tmp_path / "two.safetensors")
    no_ids = Actor(dataclasses.replace(SPECS[0], use_robot_id=False))
    with pytest.raises(ConfigError, match="differs"):
        load_actor_into(no_ids, tmp_path / "two.safetensors")


@pytest.mark.parametrize("spec", SPECS, ids=["mlp_gru", "gru_only", "linear"])
def test_init_temperature_divides_the_logits(spec: ActorSpec, tmp_path: Path) -> None:
    """actor.init_temperature T starts from softmax(logits / T): the same greedy action, a
    higher entropy for T > 1 (the remedy for a warm actor too deterministic to explore)."""
    src = _trained(spec, tmp_path / "two.safetensors")
    warm = Actor(spec)
    load_actor_into(warm, tmp_path / "two.safetensors", temperature=3.0)
    rt = ActorRuntime.from_weights(warm.export(1))
    obs = np.random.default_rng(3).normal(size=(64, 9)).astype(np.float32)
    ids = np.arange(64) % 2
    cold = src.step(obs, src.initial_state(64), robot_id=ids)[0]
    hot = rt.step(obs, rt.initial_state(64), robot_id=ids)[0]
    np.testing.assert_allclose(hot, cold / 3.0, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(hot.argmax(1), cold.argmax(1))

    def entropy(logits: np.ndarray) -> float:
        p = np.exp(logits - logits.max(1, keepdims=True))
        p /= p.sum(1, keepdims=True)
        return float(-(p * np.log(p)).sum(1).mean())

    assert entropy(hot) > entropy(cold)


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "inf"])
def test_init_temperature_must_be_positive_and_finite(bad: str) -> None:
    cfg = Config()
    set_field(cfg, "actor.init_temperature", bad)
    with pytest.raises(ConfigError, match=r"actor\.init_temperature"):
        validate(cfg)
