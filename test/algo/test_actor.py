"""NumPy runtime == torch actor; weights format validation."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from sdhn_policy import actor_runtime
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import (
    ACTOR_FORMAT,
    ActorSpec,
    ActorWeights,
    WeightsError,
    decode_weights,
    encode_actor,
    load_actor_file,
    save_actor_file,
    sha256_hex,
)

SPECS = [
    ActorSpec(obs_size=57, num_actions=5),
    ActorSpec(obs_size=9, num_actions=4, hidden_sizes=(32, 16), gru_hidden=24, use_robot_id=True,
              num_robots=3),
    # feed-forward (EPyMARL's use_rnn: false): no GRU, hidden states of width 0
    ActorSpec(obs_size=71, num_actions=5, hidden_sizes=(128,), gru_hidden=0, use_robot_id=True,
              num_robots=3),
]


def _perturbed(spec: ActorSpec) -> Actor:
    actor = Actor(spec)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.3 * torch.randn_like(p))  # the head starts near zero; make logits non-trivial
    return actor


@pytest.mark.parametrize("spec", SPECS, ids=["plain", "robot_id", "feed_forward"])
def test_numpy_runtime_equals_torch_over_random_sequences(spec: ActorSpec) -> None:
    actor = _perturbed(spec)
    rt = ActorRuntime.from_weights(actor.export(version=7))
    assert rt.version == 7
    n, t_len = 3, 40
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(t_len, n, spec.obs_size)).astype(np.float32) * 2
    resets = rng.random((t_len, n)) < 0.1
    resets[0] = False
    h_np = rt.initial_state(n)
    ids = np.arange(n) if spec.use_robot_id else None
    logits_np = []
    for t in range(t_len):
        h_np = np.where(resets[t][:, None], 0.0, h_np).astype(np.float32)
        logits, h_np = rt.step(obs[t], h_np, robot_id=ids)
        logits_np.append(logits)
    with torch.no_grad():
        x = actor.with_robot_id(torch.from_numpy(obs))
        want = actor.forward_sequence(x, torch.zeros(n, spec.gru_hidden), torch.from_numpy(resets))
    np.testing.assert_allclose(np.stack(logits_np), want.numpy(), atol=1e-5, rtol=0)


def test_runtime_act_greedy_and_sampled() -> None:
    spec = SPECS[0]
    rt = ActorRuntime.from_weights(_perturbed(spec).export(1))
    obs = np.random.default_rng(1).normal(size=(2000, spec.obs_size)).astype(np.float32)
    h = rt.initial_state(2000)
    logits, _ = rt.step(obs, h)
    a, logp, h2 = rt.act(obs, h, greedy=True, rng=np.random.default_rng(0))
    assert np.array_equal(a, logits.argmax(-1)) and h2.shape == h.shape
    # sampled actions follow the policy: compare frequencies for one fixed observation
    one = np.repeat(obs[:1], 20000, axis=0)
    a, logp, _ = rt.act(one, rt.initial_state(20000), greedy=False, rng=np.random.default_rng(0))
    probs = np.exp(actor_runtime.log_softmax(rt.step(one[:1], rt.initial_state(1))[0]))[0]
    freq = np.bincount(a, minlength=spec.num_actions) / len(a)
    np.testing.assert_allclose(freq, probs, atol=0.015)
    np.testing.assert_allclose(logp, np.log(probs[a]), atol=1e-5)



@pytest.mark.parametrize("temperature", [0.25, 0.5, 2.0])
def test_runtime_samples_at_a_temperature(temperature: float) -> None:
    """Sampled play at temperature T follows softmax(logits / T); the log-prob returned stays the
    policy's own (what PPO trains on); T = 1 draws exactly what the plain policy draws."""
    spec = SPECS[0]
    rt = ActorRuntime.from_weights(_perturbed(spec).export(1))
    obs = np.random.default_rng(2).normal(size=(1, spec.obs_size)).astype(np.float32)
    one = np.repeat(obs, 20000, axis=0)
    h = rt.initial_state(20000)
    a, logp, _ = rt.act(one, h, greedy=False, rng=np.random.default_rng(0),
                        temperature=temperature)
    logits = rt.step(obs, rt.initial_state(1))[0][0].astype(np.float64)
    tempered = np.exp(logits / temperature - np.max(logits / temperature))
    freq = np.bincount(a, minlength=spec.num_actions) / len(a)
    np.testing.assert_allclose(freq, tempered / tempered.sum(), atol=0.015)
    policy = np.exp(actor_runtime.log_softmax(logits[None].astype(np.float32)))[0]
    np.testing.assert_allclose(logp, np.log(policy[a]), atol=1e-5)
    plain, _, _ = rt.act(one, h, greedy=False, rng=np.random.default_rng(0))
    at_one, _, _ = rt.act(one, h, greedy=False, rng=np.random.default_rng(0), temperature=1.0)
    assert np.array_equal(plain, at_one)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_runtime_refuses_a_bad_temperature(bad: float) -> None:
    rt = ActorRuntime.from_weights(_perturbed(SPECS[0]).export(1))
    obs = np.zeros((1, SPECS[0].obs_size), dtype=np.float32)
    with pytest.raises(ValueError, match="temperature"):
        rt.act(obs, rt.initial_state(1), greedy=False, rng=np.random.default_rng(0),
               temperature=bad)

def test_runtime_imports_no_torch() -> None:
    for mod in (actor_runtime, __import__("sdhn_policy.weights", fromlist=["x"])):
        tree = ast.parse(Path(mod.__file__).read_text())
        names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
                 for a in n.names}
        names |= {(n.module or "").split(".")[0] for n in ast.walk(tree)
                  if isinstance(n, ast.ImportFrom)}
        assert "torch" not in names, f"{mod.__name__} imports torch"


def _blob() -> ActorWeights:
    return Actor(SPECS[1]).export(version=3)


def test_bytes_roundtrip_and_file_roundtrip(tmp_path: Path) -> None:
    blob = _blob()
    spec, tensors = decode_weights(blob)
    assert spec == SPECS[1] and set(tensors) == set(spec.tensor_shapes())
    path = tmp_path / "actor.safetensors"
    save_actor_file(path, blob)
    assert load_actor_file(path) == blob
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["format"] == ACTOR_FORMAT and side["sha256"] == blob.sha256
    assert not list(tmp_path.glob(".*tmp")), "temp files must not be left behind"


def _reencode(mutate) -> ActorWeights:  # type: ignore[no-untyped-def]
    spec, tensors = decode_weights(_blob())
    tensors = dict(tensors)
    mutate(tensors)
    from safetensors.numpy import save

    meta = {"format": ACTOR_FORMAT, "version": "3", "spec": json.dumps(spec.to_json())}
    payload = save(tensors, metadata=meta)
    return ActorWeights(ACTOR_FORMAT, 3, payload, sha256_hex(payload))


@pytest.mark.parametrize(("make", "match"), [
    (lambda b: ActorWeights(b.format, b.version, b.payload, "0" * 64), "sha256"),
    (lambda b: ActorWeights("sdhn-actor/99", b.version, b.payload, b.sha256), "unknown weights"),
    (lambda b: ActorWeights(b.format, b.version + 1, b.payload, b.sha256), "version"),
    (lambda b: ActorWeights(b.format, b.version, b.payload[:-4], sha256_hex(b.payload[:-4])),
     "safetensors"),
    (lambda b: ActorWeights(b.format, b.version, b"junk", sha256_hex(b"junk")), "payload"),
    (lambda b: _reencode(lambda t: t.update({"head.weight": np.zeros((9, 24), np.float32)})),
     "shape"),
    (lambda b: _reencode(lambda t: t.update({"extra": np.zeros(2, np.float32)})), "unexpected"),
    (lambda b: _reencode(lambda t: t.pop("gru.bias_hh")), "missing"),
    (lambda b: _reencode(lambda t: t.update({"head.bias": np.full(4, np.nan, np.float32)})), "NaN"),
], ids=["bad_sha", "unknown_format", "version_mismatch", "truncated", "junk", "wrong_shape",
        "extra_name", "missing_name", "nan"])
def test_weights_validation_errors(make, match: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(WeightsError, match=match):
        ActorRuntime.from_weights(make(_blob()))


def test_encode_rejects_wrong_tensors() -> None:
    with pytest.raises(WeightsError, match="missing"):
        encode_actor(SPECS[0], {}, 1)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match="missing weights file"):
        load_actor_file(tmp_path / "nope.safetensors")
    blob = _blob()
    path = tmp_path / "a.safetensors"
    save_actor_file(path, blob)
    path.write_bytes(blob.payload[:-1] + b"\x00")
    with pytest.raises(WeightsError, match="sha256"):
        load_actor_file(path)
