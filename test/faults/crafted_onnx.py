"""Crafted ``actor.onnx`` models built with the ``onnx`` helper API: a spec in the metadata, and
outputs that keep to the actor contract or depart from it as a :class:`Craft` says (used by
test/algo/test_onnx_contract.py and the actor's configure test)."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from onnx import TensorProto, helper, numpy_helper

from sdhn_policy.weights import ActorSpec

SPEC = ActorSpec(obs_size=6, num_actions=5, hidden_sizes=(8,), gru_hidden=4)
DTYPES = {"float": TensorProto.FLOAT, "int64": TensorProto.INT64, "double": TensorProto.DOUBLE}


@dataclass(frozen=True)
class Craft:
    """How a crafted graph departs from the contract (the defaults keep to it)."""

    logits_name: str = "logits"
    hidden_name: str = "hidden_out"
    logits_width: int = SPEC.num_actions
    hidden_width: int = SPEC.gru_hidden
    logits_dtype: str = "float"
    logits_rank: int = 2
    declared: str = "static"  # output shapes as declared: static sizes, or "dynamic" (names)
    poison: str = "none"  # none | nan | inf | nan_if_positive (NaN when obs[:, 0] > 0)
    drop_hidden: bool = False  # leave hidden_out out of the outputs


def crafted(c: Craft, spec: ActorSpec = SPEC) -> bytes:
    """A small model with the spec in its metadata and the outputs ``c`` describes."""
    rng = np.random.default_rng(0)
    d = spec.obs_size
    inits = [numpy_helper.from_array(rng.normal(size=(d, c.logits_width)).astype(np.float32), "wl"),
             numpy_helper.from_array(rng.normal(size=(d, c.hidden_width)).astype(np.float32), "wh"),
             numpy_helper.from_array(np.array({"nan": np.nan, "inf": np.inf}.get(c.poison, 0.0),
                                              np.float32), "poison"),
             numpy_helper.from_array(np.array([0], np.int64), "s0"),
             numpy_helper.from_array(np.array([1], np.int64), "s1"),
             numpy_helper.from_array(np.array([1], np.int64), "axis1")]
    nodes = [helper.make_node("MatMul", ["obs", "wl"], ["l0"]),
             helper.make_node("Add", ["l0", "poison"], ["l1"])]
    last = "l1"
    if c.poison == "nan_if_positive":
        nodes += [helper.make_node("Slice", ["obs", "s0", "s1", "axis1"], ["first"]),
                  helper.make_node("Neg", ["first"], ["neg"]),
                  helper.make_node("Sqrt", ["neg"], ["root"]),  # NaN where obs[:, 0] > 0
                  helper.make_node("Add", [last, "root"], ["l2"])]
        last = "l2"
    if c.logits_rank == 1:
        nodes.append(helper.make_node("ReduceSum", [last, "axis1"], ["l3"], keepdims=0))
        last = "l3"
    nodes.append(helper.make_node("Cast", [last], [c.logits_name], to=DTYPES[c.logits_dtype]))
    nodes.append(helper.make_node("MatMul", ["obs", "wh"], [c.hidden_name]))
    dyn = c.declared == "dynamic"
    logits_shape: list[int | str] = (["X"] if c.logits_rank == 1 else
                                     ["X", "A" if dyn else c.logits_width])
    outputs = [helper.make_tensor_value_info(c.logits_name, DTYPES[c.logits_dtype], logits_shape)]
    if not c.drop_hidden:
        outputs.append(helper.make_tensor_value_info(c.hidden_name, TensorProto.FLOAT,
                                                     ["X", "H" if dyn else c.hidden_width]))
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["X", d]),
              helper.make_tensor_value_info("hidden", TensorProto.FLOAT, ["X", spec.gru_hidden])]
    model = helper.make_model(helper.make_graph(nodes, "crafted", inputs, outputs, inits),
                              opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 9
    helper.set_model_props(model, {"sdhn.actor_spec": json.dumps(spec.to_json()),
                                   "sdhn.weights_version": "1"})
    return model.SerializeToString()
