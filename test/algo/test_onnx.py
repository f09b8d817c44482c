"""ONNX export of the actor: onnxruntime gives the NumPy runtime's outputs and actions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from sdhn_policy.actor_core import ActorCore, Decision, runtime_class
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.onnx_export import actor_to_onnx, io_contract, write_onnx
from sdhn_policy.onnx_runtime import OnnxActorRuntime
from sdhn_policy.weights import ActorSpec, WeightsError, encode_actor
from sdhn_sim.envs.registry import make_env
from sdhn_sim.recording.reader import read_recording

ROOT = Path(__file__).resolve().parents[2]
MODELS = sorted(p for p in (ROOT / "models").iterdir() if (p / "actor.safetensors").is_file())
RECORDING = ROOT / "test" / "fixtures" / "maif-tiny-pre-instance-id.mcap"


def _random_weights(spec: ActorSpec, seed: int = 0) -> dict[str, np.ndarray]:
    """Random tensors in torch's layout, scaled so logits and the GRU are far from zero."""
    rng = np.random.default_rng(seed)
    sizes = [spec.input_size, *spec.hidden_sizes]
    h = spec.gru_hidden
    shapes = {"gru.weight_ih": (3 * h, sizes[-1]), "gru.weight_hh": (3 * h, h),
              "gru.bias_ih": (3 * h,), "gru.bias_hh": (3 * h,),
              "head.weight": (spec.num_actions, h), "head.bias": (spec.num_actions,)}
    if h == 0:  # feed-forward: no GRU, the head reads the last encoder layer
        shapes = {"head.weight": (spec.num_actions, sizes[-1]), "head.bias": (spec.num_actions,)}
    for k in range(len(spec.hidden_sizes)):
        shapes[f"encoder.{k}.weight"] = (sizes[k + 1], sizes[k])
        shapes[f"encoder.{k}.bias"] = (sizes[k + 1],)
    return {k: (rng.normal(size=s) * 0.5).astype(np.float32) for k, s in shapes.items()}


def _both(spec: ActorSpec, seed: int = 0) -> tuple[ActorRuntime, OnnxActorRuntime]:
    """The NumPy and the ONNX runtime of one set of weights (through the weights format)."""
    blob = encode_actor(spec, _random_weights(spec, seed), version=3)
    return ActorRuntime.from_weights(blob), OnnxActorRuntime.from_weights(blob)


def _recorded_maif_tiny_obs() -> np.ndarray:
    """Every robot observation of the recorded maif-tiny episodes, [T, 57] in recording order."""
    rec = read_recording(RECORDING)
    obs = [np.asarray(msg.obs, dtype=np.float32) for _, msg in rec.decoded("/obs")]
    assert len(obs) > 100, f"the fixture holds only {len(obs)} observations"
    return np.stack(obs)


def _rware_observations(env_name: str, steps: int) -> np.ndarray:
    """[T, N, D] observations of one RWARE env played with seeded random actions."""
    from sdhn_sim.envs import make_env

    env = make_env(env_name, num_envs=1, seed=0)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    out = []
    for _ in range(steps):
        out.append(obs[0])
        obs = env.step(rng.integers(0, env.num_actions, size=(1, env.num_robots))).obs
    return np.stack(out).astype(np.float32)


def _rollout(rt: ActorRuntime, obs: np.ndarray, ids: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """Run a [T, X, D] sequence through ``rt`` keeping the GRU state: logits [T, X, A]."""
    h = rt.initial_state(obs.shape[1])
    logits = []
    for t in range(obs.shape[0]):
        lg, h = rt.step(obs[t], h, robot_id=ids)
        logits.append(lg)
    return np.stack(logits), h


SPECS = {
    "maif-ego": ActorSpec(obs_size=57, num_actions=5, features="maif-ego/1"),
    "robot-id": ActorSpec(obs_size=57, num_actions=5, hidden_sizes=(32, 16), gru_hidden=24,
                          use_robot_id=True, num_robots=4, features="maif-ego/1"),
    "identity": ActorSpec(obs_size=71, num_actions=5, hidden_sizes=(64,), gru_hidden=64),
    "feed-forward": ActorSpec(obs_size=71, num_actions=5, hidden_sizes=(128,), gru_hidden=0,
                              use_robot_id=True, num_robots=2),
}


@pytest.mark.parametrize("name", SPECS)
def test_onnx_equals_numpy_runtime_over_sequences(name: str) -> None:
    spec = SPECS[name]
    rt_np, rt_onnx = _both(spec)
    if spec.features == "maif-ego/1":  # real observations, different ones at every step
        env = make_env("maif-tiny", num_envs=3, seed=0)
        env.reset()
        rng = np.random.default_rng(1)
        obs = np.stack([env.step(rng.integers(0, 5, size=(3, 4))).obs.reshape(-1, 57)
                        for _ in range(30)])
    else:
        obs = np.random.default_rng(1).normal(size=(30, 5, spec.obs_size)).astype(np.float32)
    ids = np.arange(obs.shape[1]) % spec.num_robots if spec.use_robot_id else None
    got, h_got = _rollout(rt_onnx, obs, ids)
    want, h_want = _rollout(rt_np, obs, ids)
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=1e-5)
    np.testing.assert_allclose(h_got, h_want, atol=1e-5, rtol=1e-5)
    assert np.abs(want).max() > 0.5, "logits too small for the comparison to mean anything"


@pytest.mark.parametrize("model", MODELS, ids=[p.name for p in MODELS])
def test_shipped_actor_onnx_matches_numpy_on_recorded_observations(model: Path) -> None:
    """Each shipped actor, exported, on the recorded maif-tiny observations (greedy actions
    equal, logits to 1e-5); MAIF actors of other team sizes take the same 57-float layout."""
    rt_np = ActorRuntime.from_file(model / "actor.safetensors")
    rt_onnx = OnnxActorRuntime.from_file(model / "actor.safetensors")
    env = json.loads((model / "card.json").read_text())["env"]
    if env.startswith("rware"):  # no RWARE recording: its own env's observations, random play
        x = rt_np.spec.num_robots
        seq = _rware_observations(env, steps=200)
    elif rt_np.spec.obs_size == 57:
        obs = _recorded_maif_tiny_obs()
        x = 4
        seq = obs[: (len(obs) // x) * x].reshape(-1, x, 57)[:200]
    else:
        pytest.fail(f"{model.name}: neither MAIF nor RWARE; add its observations here")
    ids = np.arange(x) % max(rt_np.spec.num_robots, 1) if rt_np.spec.use_robot_id else None
    got, _ = _rollout(rt_onnx, seq, ids)
    want, _ = _rollout(rt_np, seq, ids)
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=1e-5)
    assert (got.argmax(-1) == want.argmax(-1)).all()


def test_written_onnx_file_runs_alone_with_its_contract(tmp_path: Path) -> None:
    spec = SPECS["robot-id"]
    tensors = _random_weights(spec)
    rt_np = ActorRuntime.from_weights(encode_actor(spec, tensors, version=5))
    path = write_onnx(tmp_path / "actor.onnx", spec, tensors, env_family="maif")
    contract = json.loads((tmp_path / "actor.onnx.json").read_text())
    assert contract["inputs"]["robot_id"]["shape"] == ["X"]
    assert contract["outputs"]["logits"]["shape"] == ["X", 5]
    assert contract["actions"][0] == "stay" and contract["features"] == "maif-ego/1"
    assert contract["inputs"]["hidden"]["shape"] == ["X", spec.gru_hidden]
    loaded = OnnxActorRuntime.from_onnx_file(path)
    assert loaded.spec == spec
    obs = make_env("maif-tiny", num_envs=1, seed=3).reset()[0][0]
    ids = np.arange(4)
    np.testing.assert_allclose(loaded.step(obs, loaded.initial_state(4), ids)[0],
                               rt_np.step(obs, rt_np.initial_state(4), ids)[0], atol=1e-5)
    model = onnx.load(str(path))
    assert [i.name for i in model.graph.input] == ["obs", "hidden", "robot_id"]


def test_not_an_actor_onnx_file_is_one_error(tmp_path: Path) -> None:
    bad = tmp_path / "x.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(WeightsError, match="not a readable sdhn actor ONNX file"):
        OnnxActorRuntime.from_onnx_file(bad)


def test_unknown_features_have_no_onnx_form() -> None:
    spec = ActorSpec(obs_size=57, num_actions=5, features="maif-ego/1")
    tensors = _random_weights(spec)
    object.__setattr__(spec, "features", "made-up/9")
    with pytest.raises(ValueError, match="have no ONNX form"):
        actor_to_onnx(spec, tensors)


def test_actor_core_acts_the_same_on_either_backend() -> None:
    """Sampled actions too: both runtimes share the sampler, so one seed gives one sequence."""
    blob = encode_actor(SPECS["maif-ego"], _random_weights(SPECS["maif-ego"]), version=2)
    cores = [ActorCore(1, 4, greedy=False, seed=9, runtime_cls=runtime_class(b))
             for b in ("numpy", "onnx")]
    for core in cores:
        assert core.offer_weights(blob.format, blob.version, blob.payload, blob.sha256)
    env = make_env("maif-tiny", num_envs=1, seed=2)
    obs = env.reset()[0][0]  # [4, 57]
    decisions: list[list[int]] = [[], []]
    for step in range(60):
        for k, core in enumerate(cores):
            out = core.on_obs(0, step, 1, 4, obs[1])
            assert isinstance(out, Decision), out
            decisions[k].append(out.action)
        obs = env.step(np.array([[decisions[0][-1]] * 4])).obs[0]
    assert decisions[0] == decisions[1]
    assert len(set(decisions[0])) > 1, "a constant policy would not test the sampler"


def test_unknown_backend_is_refused() -> None:
    with pytest.raises(ValueError, match="allowed: numpy, onnx"):
        runtime_class("tensorrt")


def test_io_contract_names_rware_actions() -> None:
    spec = ActorSpec(obs_size=71, num_actions=5)
    assert io_contract(spec, "rware")["actions"] == ["noop", "forward", "left", "right",
                                                     "toggle_load"]
