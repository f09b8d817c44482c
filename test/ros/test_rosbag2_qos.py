"""The rosbag2 QoS text: our profiles survive writing and reading back, rosbag2's older numeric form
reads too, a topic's offers adapt to one replay profile as ``ros2 bag play`` adapts them, and a
text that is not rosbag2's QoS list is refused with the field named."""

from __future__ import annotations

import random
from typing import Any

import pytest
import yaml
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sdhn_base.ros.qos import LATCHED, LATCHED_RECORDER, SENSOR, STEP
from sdhn_sim.recording.rosbag2 import (
    QOS_KEYS,
    QosFormatError,
    fill_history,
    offered_qos_yaml,
    parse_offered_qos,
    qos_dict,
    replay_profile,
)

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


@pytest.mark.parametrize("edit,field", [
    (("reliability: reliable", "reliability: 99"), "reliability"),
    (("history: keep_last", "history: -3"), "history"),
    (("sec: 0", "sec: -100000000000000000000", 1), "deadline"),
    (("sec: 0", "sec: 100000000000000000000000", 1), "deadline"),
    (("depth: 256", "depth: 1000000000000"), "depth"),
    (("depth: 256", "depth: true"), "depth"),
    (("avoid_ros_namespace_conventions: false", "avoid_ros_namespace_conventions: 'no'"),
     "avoid_ros_namespace_conventions"),
])
def test_crafted_qos_values_are_refused_naming_the_field(edit: tuple[Any, ...],
                                                         field: str) -> None:
    """Issue 54 item 6: these gave ValueError, OverflowError and a pybind TypeError, tracebacks
    in replay --rate (and 'no' was taken as true)."""
    text = offered_qos_yaml([STEP]).replace(*edit)
    assert text != offered_qos_yaml([STEP]), edit
    with pytest.raises(QosFormatError, match=field) as caught:
        parse_offered_qos(text)
    assert "\n" not in str(caught.value) and len(str(caught.value)) < 400


def test_an_unreadable_recorded_profile_falls_back_with_one_warning() -> None:
    from types import SimpleNamespace

    from sdhn_sim.recording.rosbag2 import QOS_KEY, recorded_profile

    warnings: list[str] = []
    channel = SimpleNamespace(topic="/sdhn/state", metadata={
        QOS_KEY: offered_qos_yaml([STEP]).replace("reliability: reliable", "reliability: 99")})
    assert recorded_profile(channel, warnings.append) is None
    assert len(warnings) == 1 and "/sdhn/state" in warnings[0] and "reliability" in warnings[0]


def _fuzz_value(rng: random.Random) -> Any:
    return rng.choice([0, 1, -1, 2, 99, 2**31, 2**63, 2**64, -(2**63) - 1, 10**30, 1.5, -1e20,
                       float("nan"), float("inf"), True, False, None, "", "reliable",
                       "keep_last", "transient_local", "automatic", "x" * 500, [], [1, 2], {},
                       {"sec": rng.choice([0, -1, 2**64, "1"]), "nsec": rng.choice([0, -5, 1e9])},
                       {"sec": 1, "nsec": 2}])


def test_fuzzed_qos_texts_parse_or_are_one_line_refusals() -> None:
    """Item 9: 1,500 seeded offered_qos_profiles texts (valid lists of 1-3 profiles with 1-3
    values replaced by odd ones, key deletions, byte edits of the text): each parses into
    profiles that replay_profile adapts, or is a QosFormatError of one bounded line."""
    rng = random.Random(54)
    base = offered_qos_yaml([STEP, SENSOR, LATCHED])
    parsed = refused = 0
    for _ in range(1500):  # ~2.5 ms of CPU each (the bounded YAML loader is pure Python)
        kind = rng.randrange(3)
        if kind == 0:
            entries = [dict(qos_dict(q)) for q in rng.sample([STEP, SENSOR, LATCHED],
                                                             rng.randrange(1, 4))]
            for _ in range(rng.randrange(1, 4)):
                entry = rng.choice(entries)
                entry[rng.choice(QOS_KEYS)] = _fuzz_value(rng)
            text = yaml.safe_dump(entries)
        elif kind == 1:
            entries = [dict(qos_dict(q)) for q in (STEP, SENSOR)]
            del entries[rng.randrange(2)][rng.choice(QOS_KEYS)]
            text = yaml.safe_dump(entries)
        else:
            chars = list(base)
            for _ in range(rng.randrange(1, 6)):
                chars[rng.randrange(len(chars))] = chr(rng.randrange(32, 127))
            text = "".join(chars)
        try:
            profiles = parse_offered_qos(text)
        except QosFormatError as e:
            assert "\n" not in str(e) and len(str(e)) < 600, str(e)
            refused += 1
            continue
        replay_profile(profiles)
        parsed += 1
    assert parsed > 15 and refused > 500, (parsed, refused)
