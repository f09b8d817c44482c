"""The shared actor as an ONNX graph: raw observation in, logits and next GRU state out.

Built directly from the actor's tensors with ``onnx.helper`` (no torch, no tracing), so the graph
computes exactly what :class:`sdhn_policy.actor_runtime.ActorRuntime` computes, op for op, and the
file can be written from a shipped ``actor.safetensors`` alone::

    model = actor_to_onnx(spec, tensors)          # onnx.ModelProto
    write_onnx(model_dir / "actor.onnx", spec, tensors)   # + actor.onnx.json (the I/O contract)

The graph includes the feature transform named in the spec (``identity`` or ``maif-ego/1``,
:mod:`sdhn_policy.features`), so a caller feeds the observation exactly as the environment sends
it. Inputs: ``obs`` float32 [X, D], ``hidden`` float32 [X, H] and, for actors trained with a
one-hot robot id, ``robot_id`` int64 [X]. Outputs: ``logits`` float32 [X, A] and ``hidden_out``
float32 [X, H]. X is any number of robots (a dynamic axis). Choosing the action (argmax, or
sampling from softmax(logits)) stays with the caller, as it does for the NumPy runtime.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from sdhn_policy.features import _CENTRE, _COORDS, _ON_GOAL_EPS, _WIN, IDENTITY, MAIF_EGO
from sdhn_policy.weights import ActorSpec, Tensors, atomic_write_bytes

OPSET = 17
IO_CONTRACT_VERSION = 1
ACTION_MAPS = {
    # the action index -> meaning of each family, in the environments' own order
    "maif": ["stay", "up (y-1)", "down (y+1)", "left (x-1)", "right (x+1)"],
    "rware": ["noop", "forward", "left", "right", "toggle_load"],
}


class _Graph:
    """A tiny builder: named nodes and constants, so the export reads like the NumPy runtime."""

    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._n = 0

    def name(self, hint: str) -> str:
        self._n += 1
        return f"{hint}_{self._n}"

    def const(self, value: Any, hint: str, dtype: Any = np.float32) -> str:
        name = self.name(hint)
        self.inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(self, op_type: str, inputs: list[str], hint: str = "", **attrs: Any) -> str:
        out = self.name(hint or op_type.lower())
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def cols(self, x: str, start: int, stop: int) -> str:
        """x[:, start:stop]."""
        return self.op("Slice", [x, self.const([start], "s", np.int64),
                                 self.const([stop], "e", np.int64),
                                 self.const([1], "ax", np.int64)], "cols")

    def as_float(self, x: str) -> str:
        return self.op("Cast", [x], "f", to=TensorProto.FLOAT)


def _maif_ego(g: _Graph, obs: str) -> str:
    """``maif-ego/1`` as graph ops, in the order of :func:`sdhn_policy.features.maif_ego`."""
    x, y, mx, my, gx, gy, mgx, mgy = (g.cols(obs, k, k + 1) for k in range(_COORDS))
    dx, dy = g.op("Sub", [gx, x]), g.op("Sub", [gy, y])
    l1 = g.op("Add", [g.op("Abs", [dx]), g.op("Abs", [dy])])
    on_goal = g.as_float(g.op("Less", [l1, g.const(_ON_GOAL_EPS, "eps")]))
    fx = g.op("Sub", [g.op("Sub", [x, mx]), g.op("Sub", [gx, mgx])])
    fy = g.op("Sub", [g.op("Sub", [y, my]), g.op("Sub", [gy, mgy])])
    win = g.cols(obs, _COORDS, _COORDS + _WIN * _WIN)
    neighbours = g.const([_CENTRE - _WIN, _CENTRE + _WIN, _CENTRE - 1, _CENTRE + 1], "nb",
                         np.int64)
    zero = g.const(0.0, "zero")
    blocked = g.as_float(g.op("Not", [g.op("Equal", [g.op("Gather", [win, neighbours], axis=1),
                                                     zero])]))
    obstacle = g.as_float(g.op("Equal", [win, g.const(1.0, "one")]))
    robot = g.as_float(g.op("Equal", [win, g.const(2.0, "two")]))
    parts = [dx, dy, g.op("Sign", [dx]), g.op("Sign", [dy]), l1, on_goal, fx, fy,
             g.op("Sign", [fx]), g.op("Sign", [fy]), g.op("Sub", [mgx, mx]),
             g.op("Sub", [mgy, my]), blocked, obstacle, robot]
    return g.op("Concat", parts, "features", axis=1)


def _linear(g: _Graph, x: str, weight: np.ndarray, bias: np.ndarray, hint: str) -> str:
    """x @ weight.T + bias (torch's Linear layout)."""
    w = g.const(np.ascontiguousarray(weight.T), f"{hint}_w")
    return g.op("Add", [g.op("MatMul", [x, w]), g.const(bias, f"{hint}_b")], hint)


def _gru_head(g: _Graph, spec: ActorSpec, tensors: Tensors, x: str) -> str:
    """The GRU cell (torch's gate order r, z, n) writing ``hidden_out``, then the head: logits."""
    gi = _linear(g, x, tensors["gru.weight_ih"], tensors["gru.bias_ih"], "gi")
    gh = _linear(g, "hidden", tensors["gru.weight_hh"], tensors["gru.bias_hh"], "gh")
    h = spec.gru_hidden
    gi_r, gi_z, gi_n = (g.cols(gi, k * h, (k + 1) * h) for k in range(3))  # torch: r, z, n
    gh_r, gh_z, gh_n = (g.cols(gh, k * h, (k + 1) * h) for k in range(3))
    r = g.op("Sigmoid", [g.op("Add", [gi_r, gh_r])], "r")
    z = g.op("Sigmoid", [g.op("Add", [gi_z, gh_z])], "z")
    n = g.op("Tanh", [g.op("Add", [gi_n, g.op("Mul", [r, gh_n])])], "n")
    keep = g.op("Mul", [z, "hidden"])
    new = g.op("Mul", [g.op("Sub", [g.const(1.0, "one"), z]), n])
    g.nodes.append(helper.make_node("Add", [new, keep], ["hidden_out"]))
    return _linear(g, "hidden_out", tensors["head.weight"], tensors["head.bias"], "head")


def actor_to_onnx(spec: ActorSpec, tensors: Tensors, *, version: int = 0,
                  doc: str = "") -> onnx.ModelProto:
    """The actor's forward pass as a checked ONNX model (see the module docstring)."""
    g = _Graph()
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["X", spec.obs_size]),
              helper.make_tensor_value_info("hidden", TensorProto.FLOAT, ["X", spec.gru_hidden])]
    if spec.features == IDENTITY:
        x = g.op("Identity", ["obs"], "features")
    elif spec.features == MAIF_EGO:
        x = _maif_ego(g, "obs")
    else:
        raise ValueError(f"features {spec.features!r} have no ONNX form; "
                         f"allowed: {IDENTITY!r}, {MAIF_EGO!r}")
    if spec.use_robot_id:
        inputs.append(helper.make_tensor_value_info("robot_id", TensorProto.INT64, ["X"]))
        ids = g.op("Unsqueeze", ["robot_id", g.const([1], "ax", np.int64)], "ids")
        onehot = g.as_float(g.op("Equal", [ids, g.const(np.arange(spec.num_robots)[None, :],
                                                        "range", np.int64)]))
        x = g.op("Concat", [x, onehot], "input", axis=1)
    for k in range(len(spec.hidden_sizes)):
        x = g.op("Relu", [_linear(g, x, tensors[f"encoder.{k}.weight"],
                                  tensors[f"encoder.{k}.bias"], f"enc{k}")])
    if spec.gru_hidden == 0:  # feed-forward: the [X, 0] hidden state passes through
        g.nodes.append(helper.make_node("Identity", ["hidden"], ["hidden_out"]))
        logits = _linear(g, x, tensors["head.weight"], tensors["head.bias"], "head")
    else:
        logits = _gru_head(g, spec, tensors, x)
    g.nodes.append(helper.make_node("Identity", [logits], ["logits"]))
    outputs = [helper.make_tensor_value_info("logits", TensorProto.FLOAT,
                                             ["X", spec.num_actions]),
               helper.make_tensor_value_info("hidden_out", TensorProto.FLOAT,
                                             ["X", spec.gru_hidden])]
    graph = helper.make_graph(g.nodes, "sdhn_actor", inputs, outputs, g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="sdhn_policy", doc_string=doc)
    model.ir_version = min(model.ir_version, 9)  # readable by onnxruntime releases of 2024 on
    helper.set_model_props(model, {"sdhn.actor_spec": json.dumps(spec.to_json()),
                                   "sdhn.weights_version": str(version)})
    onnx.checker.check_model(model, full_check=True)
    return model


def io_contract(spec: ActorSpec, env_family: str, version: int = 0) -> dict[str, Any]:
    """What a caller of ``actor.onnx`` must know, as written to ``actor.onnx.json``."""
    inputs: dict[str, Any] = {
        "obs": {"dtype": "float32", "shape": ["X", spec.obs_size],
                "meaning": "each robot's raw local observation, as the environment sends it"},
        "hidden": {"dtype": "float32", "shape": ["X", spec.gru_hidden],
                   "meaning": "GRU state: zeros at an episode's first step, then hidden_out"},
    }
    if spec.use_robot_id:
        inputs["robot_id"] = {"dtype": "int64", "shape": ["X"],
                              "meaning": f"robot index in [0, {spec.num_robots})"}
    return {
        "io_contract_version": IO_CONTRACT_VERSION,
        "opset": OPSET,
        "inputs": inputs,
        "outputs": {
            "logits": {"dtype": "float32", "shape": ["X", spec.num_actions],
                       "meaning": "action logits: argmax = greedy, softmax = the policy"},
            "hidden_out": {"dtype": "float32", "shape": ["X", spec.gru_hidden],
                           "meaning": "GRU state to feed back at the next step"},
        },
        "features": spec.features,
        "weights_version": version,
        "actions": ACTION_MAPS.get(env_family, [str(a) for a in range(spec.num_actions)]),
        "actor_spec": spec.to_json(),
    }


def write_onnx(path: str | os.PathLike[str], spec: ActorSpec, tensors: Tensors,
               env_family: str, version: int = 0) -> Path:
    """Write ``path`` (the model) and ``path`` + ``.json`` (the I/O contract), atomically."""
    out = Path(path)
    model = actor_to_onnx(spec, tensors, version=version,
                          doc=f"sdhn actor ({env_family}, {spec.features})")
    atomic_write_bytes(out, model.SerializeToString())
    contract = json.dumps(io_contract(spec, env_family, version), indent=2) + "\n"
    atomic_write_bytes(out.with_name(out.name + ".json"), contract.encode())
    return out
