"""The actor's forward pass on onnxruntime: the same interface and actions as the NumPy runtime.

``OnnxActorRuntime`` is an :class:`~sdhn_policy.actor_runtime.ActorRuntime` whose ``step`` runs the
graph of :func:`sdhn_policy.onnx_export.actor_to_onnx` in an onnxruntime session (one thread: an
actor process answers one robot at a time). It is built from the same validated weights as the
NumPy runtime, from a weights message or an ``actor.safetensors`` file, so switching backends
changes nothing else; ``from_onnx_file`` runs a shipped ``actor.onnx`` as it is. Action choice
(argmax or sampling) is inherited, so for the same logits the actions are the same.

A model is checked against its spec when it is loaded (``check_contract``): the inputs and the
outputs ``logits`` float32 [X, A] and ``hidden_out`` float32 [X, H] by name, type and shape, then
one step run on zeros for two robots, whose outputs must have those shapes and be finite. A model
that fails is a :class:`~sdhn_policy.weights.WeightsError` naming what is wrong (an actor's
configure refuses it with one line). Every later step checks the output shapes again
(:class:`~sdhn_policy.actor_runtime.PolicyOutputError`); finite logits are the caller's check
(``ActorCore`` drops and counts a step with NaN/Inf logits, it never acts on them).
"""

from __future__ import annotations

import json
import os

import numpy as np
import numpy.typing as npt
import onnxruntime as ort

from sdhn_policy.actor_runtime import F32, ActorRuntime, PolicyOutputError
from sdhn_policy.onnx_export import actor_to_onnx
from sdhn_policy.weights import ActorSpec, WeightsError, decode_actor, read_regular_file


def _session(model_bytes: bytes) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3  # errors only: no graph-optimiser chatter in a node's log
    return ort.InferenceSession(model_bytes, opts, providers=["CPUExecutionProvider"])


def _dims(shape: list[object]) -> str:
    return "[" + ", ".join(str(d) for d in shape) + "]"


def check_contract(session: ort.InferenceSession, spec: ActorSpec) -> None:
    """WeightsError naming the first way ``session``'s model differs from ``spec``'s contract
    (input/output names, element types, ranks, fixed sizes), then from one trial step."""
    want_in: dict[str, tuple[str, int | None]] = {
        "obs": ("tensor(float)", spec.obs_size), "hidden": ("tensor(float)", spec.gru_hidden)}
    if spec.use_robot_id:
        want_in["robot_id"] = ("tensor(int64)", None)
    want_out: dict[str, tuple[str, int | None]] = {
        "logits": ("tensor(float)", spec.num_actions),
        "hidden_out": ("tensor(float)", spec.gru_hidden)}
    for kind, args, want in (("input", session.get_inputs(), want_in),
                             ("output", session.get_outputs(), want_out)):
        have = {a.name: a for a in args}
        if (kind == "input" and set(have) != set(want)) or not set(want) <= set(have):
            raise WeightsError(f"{kind}s are {sorted(have)}; the contract says {sorted(want)}")
        for name, (dtype, size) in want.items():
            arg = have[name]
            rank = 1 if size is None else 2
            shape = list(arg.shape)
            if arg.type != dtype or len(shape) != rank:
                raise WeightsError(f"{kind} {name!r} is {arg.type} {_dims(shape)}; the contract "
                                   f"says {dtype} of rank {rank}")
            if size is not None and isinstance(shape[1], int) and shape[1] != size:
                raise WeightsError(f"{kind} {name!r} is {_dims(shape)}; the contract says "
                                   f"[X, {size}]")
    x = 2  # two robots: a batch axis that is fixed at 1 shows too
    feeds: dict[str, npt.NDArray[np.generic]] = {
        "obs": np.zeros((x, spec.obs_size), np.float32),
        "hidden": np.zeros((x, spec.gru_hidden), np.float32)}
    if spec.use_robot_id:
        feeds["robot_id"] = np.arange(x, dtype=np.int64) % max(1, spec.num_robots)
    try:
        logits, hidden_out = session.run(["logits", "hidden_out"], feeds)
    except Exception as e:  # onnxruntime's own errors: a graph that cannot run
        raise WeightsError(f"a trial step on zeros failed ({type(e).__name__}: "
                           f"{str(e)[:200]})") from None
    for name, value, size in (("logits", logits, spec.num_actions),
                              ("hidden_out", hidden_out, spec.gru_hidden)):
        got = np.asarray(value)
        if got.dtype != np.float32 or got.shape != (x, size):
            raise WeightsError(f"a trial step gave {name} {got.dtype} {list(got.shape)}; the "
                               f"contract says float32 [{x}, {size}]")
        if not np.isfinite(got).all():
            raise WeightsError(f"a trial step on zeros gave non-finite {name}")


class OnnxActorRuntime(ActorRuntime):
    """``ActorRuntime`` whose ``step`` runs the exported graph on onnxruntime."""

    def __init__(self, spec: ActorSpec, model_bytes: bytes, version: int = 0) -> None:
        # No super().__init__: the graph holds the weights and applies the features itself.
        self.spec = spec
        self.version = version
        self._session = _session(model_bytes)
        check_contract(self._session, spec)

    @classmethod
    def from_bytes(cls, fmt: str, version: int, payload: bytes, sha256: str) -> OnnxActorRuntime:
        """Build from the fields of a ``PolicyWeights`` message (validated; WeightsError if bad)."""
        spec, tensors = decode_actor(fmt, version, payload, sha256)
        return cls(spec, actor_to_onnx(spec, tensors, version=version).SerializeToString(),
                   version)

    @classmethod
    def from_onnx_file(cls, path: str | os.PathLike[str]) -> OnnxActorRuntime:
        """Run a written ``actor.onnx`` as it is (its spec read from the model's metadata)."""
        data = read_regular_file(path, 256 << 20)
        try:
            meta = _session(data).get_modelmeta().custom_metadata_map
            spec = ActorSpec.from_json(json.loads(meta["sdhn.actor_spec"]))
            version = int(meta.get("sdhn.weights_version", "0"))
        except Exception as e:  # onnxruntime's own error types, a missing key, bad JSON: bad file
            raise WeightsError(f"{path}: not a readable sdhn actor ONNX file ({e})") from e
        try:
            return cls(spec, data, version)
        except WeightsError as e:
            raise WeightsError(f"{path}: breaks the actor contract: {e.reason}") from None

    def step(
        self, obs: npt.ArrayLike, hidden: npt.ArrayLike, robot_id: int | npt.ArrayLike | None = None
    ) -> tuple[F32, F32]:
        x = np.asarray(obs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.spec.obs_size:
            raise ValueError(f"obs must be [X, {self.spec.obs_size}], got {x.shape}")
        feeds = {"obs": x, "hidden": np.asarray(hidden, dtype=np.float32)}
        if self.spec.use_robot_id:
            if robot_id is None:
                raise ValueError("this actor was trained with a one-hot robot id: pass robot_id")
            ids = np.broadcast_to(np.asarray(robot_id, dtype=np.int64), (x.shape[0],))
            if np.any(ids < 0) or np.any(ids >= self.spec.num_robots):
                raise ValueError(f"robot_id out of range [0, {self.spec.num_robots})")
            feeds["robot_id"] = np.ascontiguousarray(ids)
        logits, h_next = self._session.run(["logits", "hidden_out"], feeds)
        logits, h_next = np.asarray(logits), np.asarray(h_next)
        n = x.shape[0]
        if (logits.shape != (n, self.spec.num_actions) or h_next.shape != (n, self.spec.gru_hidden)
                or logits.dtype != np.float32 or h_next.dtype != np.float32):
            raise PolicyOutputError(
                f"the model gave logits {logits.dtype} {list(logits.shape)} and hidden_out "
                f"{h_next.dtype} {list(h_next.shape)}; the contract says float32 "
                f"[{n}, {self.spec.num_actions}] and [{n}, {self.spec.gru_hidden}]")
        return logits, h_next

