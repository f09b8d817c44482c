"""The rosbag2 QoS text: our profiles survive writing and reading back, rosbag2's older numeric form
reads too, a topic's offers adapt to one replay profile as ``ros2 bag play`` adapts them, and a
text that is not rosbag2's QoS list is refused with the field named."""

from __future__ import annotations

import pytest
import yaml
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sdhn_sim.recording.rosbag2 import (
    QosFormatError,
    fill_history,
    offered_qos_yaml,
    parse_offered_qos,
    replay_profile,
)
from sdhn_sim.ros.qos import LATCHED, LATCHED_RECORDER, SENSOR, STEP

# What the graph reports for a remote publisher of LATCHED: no history, no depth.
DISCOVERED_LATCHED = QoSProfile(history=HistoryPolicy.UNKNOWN, depth=0,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.mark.parametrize("profile", [STEP, LATCHED, LATCHED_RECORDER, SENSOR],
                         ids=["STEP", "LATCHED", "LATCHED_RECORDER", "SENSOR"])
def test_profile_survives_writing_and_reading(profile: QoSProfile) -> None:
    (back,) = parse_offered_qos(offered_qos_yaml([profile]))
    assert back == profile


def test_finite_durations_are_sec_and_nsec() -> None:
    q = QoSProfile(depth=3, deadline=Duration(seconds=1, nanoseconds=250_000_000))
    (entry,) = yaml.safe_load(offered_qos_yaml([q]))
    assert entry["deadline"] == {"sec": 1, "nsec": 250_000_000}
    assert entry["lifespan"] == {"sec": 0, "nsec": 0}  # unspecified = the default


def test_rosbag2_numeric_policies_of_older_versions_read() -> None:
    text = """
- history: 1
  depth: 5
  reliability: 2
  durability: 1
  deadline: {sec: 9223372036, nsec: 854775807}
  lifespan: {sec: 9223372036, nsec: 854775807}
  liveliness: 1
  liveliness_lease_duration: {sec: 9223372036, nsec: 854775807}
  avoid_ros_namespace_conventions: false
"""
    (q,) = parse_offered_qos(text)
    assert (q.history, q.depth, q.reliability, q.durability) == (
        HistoryPolicy.KEEP_LAST, 5, ReliabilityPolicy.BEST_EFFORT,
        DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.mark.parametrize("offers,reliable,latched,depth", [
    ([LATCHED], True, True, 1),
    ([STEP, SENSOR], False, False, STEP.depth),  # one best-effort publisher: best effort
    ([LATCHED, STEP], True, False, STEP.depth),  # one volatile publisher: volatile
    ([DISCOVERED_LATCHED], True, True, 10),  # depth unknown: rosbag2's default
])
def test_offers_adapt_to_one_replay_profile(offers: list[QoSProfile], reliable: bool,
                                            latched: bool, depth: int) -> None:
    q = replay_profile(offers)
    assert q is not None
    assert (q.reliability == ReliabilityPolicy.RELIABLE) is reliable
    assert (q.durability == DurabilityPolicy.TRANSIENT_LOCAL) is latched
    assert q.depth == depth and q.history == HistoryPolicy.KEEP_LAST
    assert replay_profile([]) is None


def test_history_is_filled_from_the_contract_only_where_it_agrees() -> None:
    (filled,) = fill_history([DISCOVERED_LATCHED], LATCHED)
    assert (filled.history, filled.depth) == (HistoryPolicy.KEEP_LAST, 1)
    (kept,) = fill_history([DISCOVERED_LATCHED], STEP)  # a volatile contract: not this publisher
    assert (kept.history, kept.depth) == (HistoryPolicy.UNKNOWN, 0)
    (own,) = fill_history([SENSOR], STEP)  # the graph knew the history: left as it is
    assert own == SENSOR


@pytest.mark.parametrize("text,field", [
    ("{history: keep_last}", "a list"),
    ("- {history: keep_last, depth: 1}", "needs keys"),
    (offered_qos_yaml([STEP]).replace("reliable", "sometimes"), "reliability"),
    (offered_qos_yaml([STEP]).replace("depth: 256", "depth: -1"), "depth"),
    (offered_qos_yaml([STEP]).replace("sec: 0", "sec: soon", 1), "deadline"),
    ("- [unclosed", "not YAML"),
])
def test_malformed_qos_text_is_refused_naming_the_field(text: str, field: str) -> None:
    with pytest.raises(QosFormatError, match=field):
        parse_offered_qos(text)
