"""Malformed and hostile messages, built one kind at a time (the test process publishes them).

Every builder returns a message that a correct node must drop; the kind names are the ones the
node counts (``sdhn_policy.actor_core`` for observations and weights, ``sdhn_sim.lockstep`` for
actions).
"""

from __future__ import annotations

import array
import hashlib
import json
import pickle
from pathlib import Path

import numpy as np
from safetensors.numpy import save as st_save

from sdhn_msgs.msg import PolicyWeights, RobotAction, RobotObservation
from sdhn_policy.weights import ACTOR_FORMAT, ActorWeights, decode_weights, encode_actor

from .crafted_weights import deep_header, deep_spec, spec_number


def obs_msg(episode: int, step: int, robot: int, n: int, obs: np.ndarray) -> RobotObservation:
    m = RobotObservation(episode=episode, step=step, robot_id=robot, num_robots=n)
    m.obs = array.array("f", np.ascontiguousarray(obs, np.float32).tobytes())
    return m


def action_msg(episode: int, step: int, robot: int, action: int, version: int = 1) -> RobotAction:
    return RobotAction(episode=episode, step=step, robot_id=robot, action=action,
                       log_prob=-1.0, policy_version=version)


def weights_msg(fmt: str, version: int, payload: bytes, sha256: str | None = None
                ) -> PolicyWeights:
    m = PolicyWeights(version=version, format=fmt,
                      sha256=sha256 if sha256 is not None else hashlib.sha256(payload).hexdigest())
    m.payload = payload
    return m


def _raw_payload(tensors: dict[str, np.ndarray], spec_json: dict, version: int) -> bytes:
    meta = {"format": ACTOR_FORMAT, "version": str(version),
            "spec": json.dumps(spec_json, sort_keys=True)}
    return st_save({k: np.ascontiguousarray(v) for k, v in tensors.items()}, metadata=meta)


class PickleBomb:
    """Unpickling this creates ``marker``: proof that a loader executed code from a payload."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (Path.touch, (self.marker,))


def hostile_weights(good: ActorWeights, version: int, marker: Path
                    ) -> dict[str, PolicyWeights]:
    """Kind -> a weights message the actor must reject, each built from the valid ``good``."""
    spec, tensors = decode_weights(good)
    valid = encode_actor(spec, tensors, version)
    shapes = dict(tensors)
    name = next(iter(shapes))
    shapes[name] = np.zeros((3, 3), np.float32)
    names = dict(tensors)
    names["encoder.0.weight_renamed"] = names.pop(next(iter(names)))
    pickled = pickle.dumps(PickleBomb(marker))
    return {
        "bad_sha256": weights_msg(valid.format, version, valid.payload, "0" * 64),
        "bad_tensors:shape": weights_msg(ACTOR_FORMAT, version,
                                         _raw_payload(shapes, spec.to_json(), version)),
        "bad_tensors:names": weights_msg(ACTOR_FORMAT, version,
                                         _raw_payload(names, spec.to_json(), version)),
        "unknown_format": weights_msg("sdhn-actor/99", version, valid.payload),
        "oversized": weights_msg(ACTOR_FORMAT, version, bytes(64 * 1024 * 1024 + 1)),
        "bad_weights:pickle": weights_msg(ACTOR_FORMAT, version, pickled),
        # each of these once raised past the drop path (RecursionError, OverflowError) and
        # took every actor down: ~400 kB of nesting, a spec number that is not finite
        "bad_weights:deep_header": weights_msg(ACTOR_FORMAT, version, deep_header(valid)),
        "bad_weights:deep_spec": weights_msg(ACTOR_FORMAT, version, deep_spec(valid)),
        "bad_weights:spec_infinity": weights_msg(ACTOR_FORMAT, version,
                                                 spec_number(valid, "obs_size", "Infinity")),
        "bad_weights:spec_overflow": weights_msg(ACTOR_FORMAT, version,
                                                 spec_number(valid, "gru_hidden", "1e999")),
    }
