"""The actor's forward pass on onnxruntime: the same interface and actions as the NumPy runtime.

``OnnxActorRuntime`` is an :class:`~sdhn_policy.actor_runtime.ActorRuntime` whose ``step`` runs the
graph of :func:`sdhn_policy.onnx_export.actor_to_onnx` in an onnxruntime session (one thread: an
actor process answers one robot at a time). It is built from the same validated weights as the
NumPy runtime, from a weights message or an ``actor.safetensors`` file, so switching backends
changes nothing else; ``from_onnx_file`` runs a shipped ``actor.onnx`` as it is. Action choice
(argmax or sampling) is inherited, so for the same logits the actions are the same.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt
import onnxruntime as ort

from sdhn_policy.actor_runtime import F32, ActorRuntime
from sdhn_policy.onnx_export import actor_to_onnx
from sdhn_policy.weights import ActorSpec, WeightsError, decode_actor


def _session(model_bytes: bytes) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3  # errors only: no graph-optimiser chatter in a node's log
    return ort.InferenceSession(model_bytes, opts, providers=["CPUExecutionProvider"])


class OnnxActorRuntime(ActorRuntime):
    """``ActorRuntime`` whose ``step`` runs the exported graph on onnxruntime."""

    def __init__(self, spec: ActorSpec, model_bytes: bytes, version: int = 0) -> None:
        # No super().__init__: the graph holds the weights and applies the features itself.
        self.spec = spec
        self.version = version
        self._session = _session(model_bytes)

    @classmethod
    def from_bytes(cls, fmt: str, version: int, payload: bytes, sha256: str) -> OnnxActorRuntime:
        """Build from the fields of a ``PolicyWeights`` message (validated; WeightsError if bad)."""
        spec, tensors = decode_actor(fmt, version, payload, sha256)
        return cls(spec, actor_to_onnx(spec, tensors, version=version).SerializeToString(),
                   version)

    @classmethod
    def from_onnx_file(cls, path: str | os.PathLike[str]) -> OnnxActorRuntime:
        """Run a written ``actor.onnx`` as it is (its spec read from the model's metadata)."""
        data = Path(path).read_bytes()
        try:
            meta = _session(data).get_modelmeta().custom_metadata_map
            spec = ActorSpec.from_json(json.loads(meta["sdhn.actor_spec"]))
            version = int(meta.get("sdhn.weights_version", "0"))
        except Exception as e:  # onnxruntime's own error types, a missing key, bad JSON: bad file
            raise WeightsError(f"{path}: not a readable sdhn actor ONNX file ({e})") from e
        return cls(spec, data, version)

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
        return np.asarray(logits, dtype=np.float32), np.asarray(h_next, dtype=np.float32)

