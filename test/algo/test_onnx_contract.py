"""Crafted ``actor.onnx`` files against the actor contract (issue 54, item 4): a model whose
outputs differ from its spec is refused at load with one line naming what differs; NaN/Inf
logits at run time are a counted drop, never an action. Plus a seeded fuzz of crafted graphs
(item 9): every one either loads and answers every step with an action or a counted drop, or is
refused with a WeightsError; nothing else escapes."""

from __future__ import annotations

import random
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import pytest
from faults.crafted_onnx import DTYPES, SPEC, Craft, crafted

from sdhn_base.drops import DropKind
from sdhn_policy.actor_core import ActorCore, Decision, Drop, runtime_from_file
from sdhn_policy.onnx_runtime import OnnxActorRuntime
from sdhn_policy.weights import WeightsError


def write(tmp_path: Path, c: Craft, name: str = "actor.onnx") -> Path:
    path = tmp_path / name
    path.write_bytes(crafted(c))
    return path


def test_a_crafted_graph_that_keeps_to_the_contract_loads_and_acts(tmp_path: Path) -> None:
    rt = runtime_from_file("onnx", str(write(tmp_path, Craft())))
    core = ActorCore(robot_id=0, num_robots=1, greedy=True, seed=0, runtime=rt)
    out = core.on_obs(0, 0, 0, 1, np.ones(SPEC.obs_size, np.float32))
    assert isinstance(out, Decision) and 0 <= out.action < SPEC.num_actions, out


REFUSED = {  # what was let through before (issue 54), and a word the one line must name
    "hidden_out [X, 3]": (Craft(hidden_width=3), "hidden_out"),
    "1-D int64 logits": (Craft(logits_dtype="int64", logits_rank=1), "logits"),
    "float64 logits": (Craft(logits_dtype="double"), "logits"),
    "no hidden_out": (Craft(drop_hidden=True), "hidden_out"),
    "outputs renamed": (Craft(logits_name="scores"), "logits"),
    "1,000 logits": (Craft(logits_width=1000), "logits"),
    "1,000 logits, declared dynamic": (Craft(logits_width=1000, declared="dynamic"), "logits"),
    "hidden [X, 3], declared dynamic": (Craft(hidden_width=3, declared="dynamic"), "hidden_out"),
    "NaN logits": (Craft(poison="nan"), "non-finite logits"),
    "inf logits": (Craft(poison="inf"), "non-finite logits"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_a_model_that_breaks_the_contract_is_refused_at_load_with_one_line(
        tmp_path: Path, case: str) -> None:
    craft, named = REFUSED[case]
    path = write(tmp_path, craft)
    with pytest.raises(WeightsError) as caught:
        runtime_from_file("onnx", str(path))
    reason = caught.value.reason
    assert "\n" not in reason and len(reason) < 400, reason
    assert str(path) in reason and named in reason, reason


def test_non_finite_logits_at_run_time_are_a_counted_drop_never_an_action(
        tmp_path: Path) -> None:
    """The graph is finite on the trial step (zeros) and NaN wherever obs[0] > 0: those steps
    are dropped (no action, before the fix a silent 'stay' with a NaN log-prob); the steps
    around them are answered, in order."""
    rt = OnnxActorRuntime.from_onnx_file(write(tmp_path, Craft(poison="nan_if_positive")))
    core = ActorCore(robot_id=0, num_robots=1, greedy=False, seed=0, runtime=rt)
    obs = np.full(SPEC.obs_size, -1.0, np.float32)
    poisoned = obs.copy()
    poisoned[0] = 1.0
    outs = [core.on_obs(0, 0, 0, 1, obs), core.on_obs(0, 1, 0, 1, poisoned),
            core.on_obs(0, 2, 0, 1, obs), core.on_obs(0, 3, 0, 1, poisoned)]
    kinds = [o.kind if isinstance(o, Drop) else "action" for o in outs]
    assert kinds == ["action", DropKind.NON_FINITE_LOGITS, "action",
                     DropKind.NON_FINITE_LOGITS], outs
    assert all(np.isfinite(o.log_prob) for o in outs if isinstance(o, Decision))
    assert core.hidden is not None and np.isfinite(core.hidden).all()


def fuzz_craft(rng: random.Random) -> Craft:
    c = Craft()
    changes = {
        "logits_name": lambda: rng.choice(["logits", "logit", "hidden_out", ""]),
        "hidden_name": lambda: rng.choice(["hidden_out", "hidden", "h"]),
        "logits_width": lambda: rng.choice([SPEC.num_actions, 0, 1, 4, 6, 1000]),
        "hidden_width": lambda: rng.choice([SPEC.gru_hidden, 0, 3, 5, 64]),
        "logits_dtype": lambda: rng.choice(list(DTYPES)),
        "logits_rank": lambda: rng.choice([1, 2]),
        "declared": lambda: rng.choice(["static", "dynamic"]),
        "poison": lambda: rng.choice(["none", "nan", "inf", "nan_if_positive"]),
        "drop_hidden": lambda: rng.random() < 0.2,
    }
    for field in rng.sample(list(changes), rng.randrange(1, 4)):
        c = replace(c, **{field: changes[field]()})
    return c


def test_fuzzed_crafted_graphs_load_and_act_or_are_refused(tmp_path: Path) -> None:
    """Item 9: 250 seeded crafted graphs (1-3 departures each from the contract): a model either
    fails with a WeightsError at load, or answers 8 steps of random observations each with an
    in-range action with a finite log-prob or a counted drop. Nothing else."""
    rng = random.Random(54)
    obs_rng = np.random.default_rng(54)
    loaded = refused = 0
    for _ in range(250):
        c = fuzz_craft(rng)
        try:
            data = crafted(c)
        except Exception:  # onnx cannot even build it (duplicate names): not a file we test
            continue
        path = tmp_path / "actor.onnx"
        path.write_bytes(data)
        try:
            rt = runtime_from_file("onnx", str(path))
        except WeightsError as e:
            assert "\n" not in e.reason, e.reason
            refused += 1
            continue
        loaded += 1
        core = ActorCore(robot_id=0, num_robots=1, greedy=rng.random() < 0.5, seed=0, runtime=rt)
        for step in range(8):
            out = core.on_obs(0, step, 0, 1, obs_rng.normal(size=SPEC.obs_size).astype(np.float32))
            if isinstance(out, Decision):
                assert 0 <= out.action < SPEC.num_actions and np.isfinite(out.log_prob), (c, out)
            else:
                assert isinstance(out, Drop) and out.kind in (
                    DropKind.NON_FINITE_LOGITS, DropKind.BAD_POLICY_OUTPUT), (c, out)
    assert loaded > 10 and refused > 100, (loaded, refused)


def test_the_shipped_export_still_loads(tmp_path: Path) -> None:
    """The project's own exporter keeps to the contract the loader now checks."""
    from sdhn_policy.onnx_export import write_onnx

    rng = np.random.default_rng(1)
    spec = SPEC
    shapes = {"encoder.0.weight": (8, 6), "encoder.0.bias": (8,), "gru.weight_ih": (12, 8),
              "gru.weight_hh": (12, 4), "gru.bias_ih": (12,), "gru.bias_hh": (12,),
              "head.weight": (5, 4), "head.bias": (5,)}
    tensors = {k: rng.normal(size=s).astype(np.float32) for k, s in shapes.items()}
    path = write_onnx(tmp_path / "actor.onnx", spec, tensors, env_family="maif")
    assert OnnxActorRuntime.from_onnx_file(path).spec == spec
    assert onnx.load(str(path)).graph.output[0].name == "logits"


def test_weights_that_overflow_are_a_drop_on_the_numpy_runtime_too() -> None:
    """Valid, finite weights so large that the forward pass overflows (a feed-forward actor whose
    encoder outputs ~1e38 and head multiplies by 1e38: inf logits) gave an action with a NaN
    log-probability."""
    from sdhn_policy.actor_runtime import ActorRuntime
    from sdhn_policy.weights import encode_actor

    spec = replace(SPEC, gru_hidden=0)
    rng = np.random.default_rng(0)
    tensors = {"encoder.0.weight": rng.normal(size=(8, 6)).astype(np.float32),
               "encoder.0.bias": np.full(8, 1e38, np.float32),
               "head.weight": np.full((5, 8), 1e38, np.float32),
               "head.bias": np.zeros(5, np.float32)}
    rt = ActorRuntime.from_weights(encode_actor(spec, tensors, version=1))
    core = ActorCore(robot_id=0, num_robots=1, greedy=False, seed=0, runtime=rt)
    outs = [core.on_obs(0, s, 0, 1, rng.normal(size=6).astype(np.float32)) for s in range(6)]
    assert all(isinstance(o, Drop) and o.kind == DropKind.NON_FINITE_LOGITS for o in outs), outs


@pytest.mark.parametrize("which", ["payload", "sidecar", "onnx"])
def test_a_fifo_as_a_weights_file_is_refused_without_opening_it(tmp_path: Path,
                                                                   which: str) -> None:
    """Issue 54 item 8: a FIFO as an actor's weights_file blocked its executor in open()."""
    import os
    import threading

    payload, sidecar = tmp_path / "actor.safetensors", tmp_path / "actor.json"
    target = {"payload": payload, "sidecar": sidecar, "onnx": tmp_path / "actor.onnx"}[which]
    for path in (payload, sidecar):
        if path != target:
            path.write_text("{}")
    os.mkfifo(target)
    backend = "onnx" if which == "onnx" else "numpy"
    errors: list[str] = []

    def load() -> None:
        try:
            runtime_from_file(backend, str(target if which == "onnx" else payload))
        except WeightsError as e:
            errors.append(e.reason)

    loader = threading.Thread(target=load, daemon=True)
    loader.start()
    loader.join(20)
    if loader.is_alive():  # unblock the reader so the test process can end
        with open(target, "wb"):
            pass
        pytest.fail(f"loading a FIFO {which} blocked")
    assert len(errors) == 1 and "not a regular file" in errors[0], errors
