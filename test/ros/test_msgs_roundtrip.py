"""Every sdhn_msgs type survives rclpy serialisation with realistic payloads, field for field."""

from __future__ import annotations

import array
import hashlib
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from sdhn_msgs.msg import (
    EpisodeSummary,
    Hypergraph,
    PolicyWeights,
    RobotAction,
    RobotObservation,
    TeamState,
)

RNG = np.random.default_rng(7)


def f32(values: np.ndarray) -> array.array:
    return array.array("f", values.astype(np.float32).tobytes())


def observation() -> RobotObservation:
    msg = RobotObservation(episode=12, step=499, robot_id=19, num_robots=20, reward=-1.25)
    msg.obs = f32(RNG.standard_normal(57))
    msg.truncated = True
    return msg


def action() -> RobotAction:
    return RobotAction(episode=3, step=41, robot_id=7, action=4, log_prob=-0.3, policy_version=9)


def team_state() -> TeamState:
    msg = TeamState(env_name="maif-20", episode=5, step=77, num_robots=20, team_reward=-2.5)
    msg.state = f32(RNG.standard_normal(20 * 57))  # 20 robots x 57 floats
    msg.positions = array.array("i", RNG.integers(0, 64, 40).astype(np.int32).tobytes())
    msg.makespan_so_far = 77
    return msg


def weights() -> PolicyWeights:
    payload = RNG.integers(0, 256, 1 << 20, dtype=np.uint8).tobytes()  # a 1 MB blob
    msg = PolicyWeights(
        version=42, format="sdhn-actor/1", sha256=hashlib.sha256(payload).hexdigest()
    )
    msg.payload = payload
    return msg


def hypergraph() -> Hypergraph:
    p_h = RNG.random((20, 10))
    msg = Hypergraph(episode=1, step=2, num_robots=20, num_hyperedges=10, skewness=-0.42)
    msg.p_h = f32(p_h.ravel())
    msg.incidence = (p_h > 0.5).astype(np.uint8).ravel().tobytes()
    return msg


def summary() -> EpisodeSummary:
    return EpisodeSummary(
        env_name="maif-10",
        episode=8,
        length=61,
        completed=True,
        makespan=61,
        episode_return=152.5,
        collisions=3,
        formation_error=0.75,
        missed_actions=1,
        policy_version=4,
    )


def as_plain(value: Any) -> Any:
    """Comparable form of a field: arrays and byte sequences become tuples."""
    if isinstance(value, array.array | np.ndarray | bytes | list):
        return tuple(np.asarray(list(value)).tolist())
    return value


@pytest.mark.parametrize(
    "make",
    [observation, action, team_state, weights, hypergraph, summary],
    ids=lambda f: f.__name__,
)
def test_message_round_trips_through_cdr(make: Any) -> None:
    original = make()
    decoded = deserialize_message(serialize_message(original), type(original))
    for field in original.get_fields_and_field_types():
        if field == "header":
            continue
        sent, got = as_plain(getattr(original, field)), as_plain(getattr(decoded, field))
        if isinstance(sent, float):
            assert got == pytest.approx(sent, rel=1e-6), f"{field}: sent {sent}, got {got}"
        else:
            assert got == sent, f"{type(original).__name__}.{field} changed in transit"


def test_weights_payload_keeps_its_checksum() -> None:
    original = weights()
    decoded = deserialize_message(serialize_message(original), PolicyWeights)
    assert hashlib.sha256(bytes(decoded.payload)).hexdigest() == original.sha256
    assert len(decoded.payload) == 1 << 20
