"""What rosbag2 (Jazzy) writes around the messages of an MCAP file, so ``ros2 bag play`` treats
our recordings as its own (docs/recording.md):

- per channel, metadata ``offered_qos_profiles``: a YAML list with one entry per publisher of the
  topic (history, depth, reliability, durability, deadline, lifespan, liveliness,
  liveliness_lease_duration, avoid_ros_namespace_conventions; policies by name, durations as
  ``{sec, nsec}``), and ``topic_type_hash`` (``RIHS01_<hex>``, empty when unknown);
- at the end, a metadata record ``rosbag2`` whose ``serialized_metadata`` is the whole BagMetadata
  (version 9) as YAML, and ``ros_distro``.

Without the QoS metadata ``ros2 bag play`` publishes every topic reliable, volatile, keep-last 10:
the latched ``policy/weights`` would lose transient-local. ``parse_offered_qos`` reads the list
back, and ``replay_profile`` turns a topic's offers into the one profile to republish it with.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from sdhn_base.yaml_io import YamlError, load_yaml

BAG_VERSION = 9
ROS_DISTRO = "jazzy"
STORAGE_IDENTIFIER = "mcap"
METADATA_RECORD = "rosbag2"  # the MCAP metadata record's name
QOS_KEY = "offered_qos_profiles"  # channel metadata keys
TYPE_HASH_KEY = "topic_type_hash"
QOS_KEYS = ("history", "depth", "reliability", "durability", "deadline", "lifespan",
            "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions")
BAG_KEYS = ("version", "storage_identifier", "duration", "starting_time", "message_count",
            "topics_with_message_count", "compression_format", "compression_mode",
            "relative_file_paths", "files", "custom_data", "ros_distro")
# rmw's RMW_DURATION_INFINITE (INT64_MAX ns), as rosbag2 writes an infinite deadline or lifespan
INFINITE = {"sec": 9223372036, "nsec": 854775807}
INFINITE_NS = 9223372036854775807
# The depth used to republish a topic whose publishers did not say theirs (DDS discovery does not
# carry history): rosbag2's default, and ours for a reliable topic with flow control.
UNKNOWN_DEPTH_REPLAY = 10
# A recorded depth above this is not a real publisher's (rclpy refused 10**12 with a TypeError;
# a depth in the millions would make the replay's writer reserve that history).
MAX_DEPTH = 100_000
MAX_OFFERS = 1_000  # publishers of one topic in one recording

_POLICIES: dict[str, Any] = {
    "history": HistoryPolicy,
    "reliability": ReliabilityPolicy,
    "durability": DurabilityPolicy,
    "liveliness": LivelinessPolicy,
}


class QosFormatError(ValueError):
    """An ``offered_qos_profiles`` text that is not rosbag2's QoS list."""


def _duration(d: Duration | None) -> dict[str, int]:
    ns = 0 if d is None else int(d.nanoseconds)
    if ns >= INFINITE_NS:
        return dict(INFINITE)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_dict(q: QoSProfile) -> dict[str, Any]:
    """One publisher's QoS as rosbag2 (version 9) writes it: keys in its order, policy names."""
    return {
        "history": q.history.name.lower(),
        "depth": int(q.depth),
        "reliability": q.reliability.name.lower(),
        "durability": q.durability.name.lower(),
        "deadline": _duration(q.deadline),
        "lifespan": _duration(q.lifespan),
        "liveliness": q.liveliness.name.lower(),
        "liveliness_lease_duration": _duration(q.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(q.avoid_ros_namespace_conventions),
    }


def fill_history(offers: Sequence[QoSProfile], contract: QoSProfile | None) -> list[QoSProfile]:
    """``offers`` as read from the graph, with history and depth taken from ``contract`` (the
    profile our own publishers of that topic use) where the graph says "unknown" and the rest
    agrees with the contract. DDS discovery carries reliability, durability, deadline, lifespan
    and liveliness but not history: the graph reports every remote publisher as history unknown,
    depth 0, and rosbag2 writes that as it is; we know better for the contract's topics."""
    filled = []
    for q in offers:
        known = (contract is not None and q.history == HistoryPolicy.UNKNOWN
                 and q.reliability == contract.reliability
                 and q.durability == contract.durability)
        filled.append(q if not known or contract is None else QoSProfile(
            history=contract.history, depth=contract.depth,
            reliability=q.reliability, durability=q.durability,
            deadline=q.deadline, lifespan=q.lifespan, liveliness=q.liveliness,
            liveliness_lease_duration=q.liveliness_lease_duration,
            avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions))
    return filled


def offered_qos_yaml(profiles: Sequence[QoSProfile]) -> str:
    """The ``offered_qos_profiles`` text of a topic: a YAML list, one entry per publisher."""
    if not profiles:
        return "[]"
    return yaml.safe_dump([qos_dict(q) for q in profiles], sort_keys=False,
                          default_flow_style=False).strip()


def type_hash_text(type_hash: Any) -> str:
    """rclpy's TypeHash as rosbag2 writes it ('RIHS01_<64 hex>'); '' when the graph has none."""
    version = getattr(type_hash, "version", -1)
    value = bytes(getattr(type_hash, "value", b""))
    if version < 1 or not any(value):
        return ""
    return f"RIHS{version:02d}_{value.hex()}"


def _policy(kind: str, value: Any) -> Any:
    enum = _POLICIES[kind]
    if isinstance(value, int) and not isinstance(value, bool):  # versions <= 8: numbers
        try:
            return enum(value)
        except ValueError:  # e.g. reliability: 99
            numbers = ", ".join(str(m.value) for m in enum)
            raise QosFormatError(f"{kind}: {value!r}; allowed: {numbers} or a name") from None
    try:
        return enum[str(value).upper()]
    except KeyError:
        names = ", ".join(m.name.lower() for m in enum)
        raise QosFormatError(f"{kind}: {_short(value)}; allowed: {names}") from None


def _parse_duration(kind: str, value: Any) -> Duration:
    """{sec, nsec} as rosbag2 writes them: integers >= 0 (more than INT64_MAX ns is infinite)."""
    if not (isinstance(value, Mapping) and all(
            isinstance(value.get(k), int) and not isinstance(value.get(k), bool)
            and 0 <= value[k] <= INFINITE_NS for k in ("sec", "nsec"))):
        raise QosFormatError(f"{kind}: {_short(value)}; allowed: {{sec: int >= 0, nsec: int >= "
                             "0}")
    ns = value["sec"] * 1_000_000_000 + value["nsec"]
    return Duration(nanoseconds=min(ns, INFINITE_NS))


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:80] + "..."


def parse_offered_qos(text: str) -> list[QoSProfile]:
    """The profiles of an ``offered_qos_profiles`` text (QosFormatError when it is not one)."""
    try:  # text from a recording: the bounded loader (no alias bombs, no duplicate keys)
        entries = load_yaml(text, what=QOS_KEY)
    except YamlError as e:
        raise QosFormatError(f"{QOS_KEY}: not YAML ({e})") from None
    if entries is None:
        return []
    if not isinstance(entries, list):
        raise QosFormatError(f"{QOS_KEY}: {type(entries).__name__}; allowed: a list")
    if len(entries) > MAX_OFFERS:
        raise QosFormatError(f"{QOS_KEY}: {len(entries)} entries; allowed: at most {MAX_OFFERS}")
    profiles = []
    for entry in entries:
        if not isinstance(entry, Mapping) or set(QOS_KEYS) - set(entry):
            raise QosFormatError(f"{QOS_KEY}: entry {_short(entry)}; needs keys "
                                 f"{', '.join(QOS_KEYS)}")
        depth = entry["depth"]
        if not isinstance(depth, int) or isinstance(depth, bool) or not 0 <= depth <= MAX_DEPTH:
            raise QosFormatError(f"depth: {_short(depth)}; allowed: an integer 0 .. {MAX_DEPTH}")
        if not isinstance(entry["avoid_ros_namespace_conventions"], bool):
            raise QosFormatError(f"avoid_ros_namespace_conventions: "
                                 f"{_short(entry['avoid_ros_namespace_conventions'])}; allowed: "
                                 "true, false")
        try:  # whatever rclpy still refuses (a value pybind cannot convert): one line too
            profiles.append(QoSProfile(
                history=_policy("history", entry["history"]),
                depth=entry["depth"],
                reliability=_policy("reliability", entry["reliability"]),
                durability=_policy("durability", entry["durability"]),
                deadline=_parse_duration("deadline", entry["deadline"]),
                lifespan=_parse_duration("lifespan", entry["lifespan"]),
                liveliness=_policy("liveliness", entry["liveliness"]),
                liveliness_lease_duration=_parse_duration("liveliness_lease_duration",
                                                          entry["liveliness_lease_duration"]),
                avoid_ros_namespace_conventions=entry["avoid_ros_namespace_conventions"],
            ))
        except QosFormatError:
            raise
        except (TypeError, ValueError, OverflowError) as e:
            raise QosFormatError(f"{QOS_KEY}: entry {_short(entry)}: {_short(str(e))}") from None
    return profiles


def replay_profile(offers: Sequence[QoSProfile]) -> QoSProfile | None:
    """The profile to republish a topic with, from its recorded offers (None: none recorded).

    As ``ros2 bag play`` adapts them: reliable only when every publisher was reliable,
    transient-local only when every publisher was, so every subscriber that matched one of the
    recorded publishers matches the replay. The depth is the largest recorded one (a latched
    topic keeps its depth 1: a late joiner gets only the latest sample, as from the original);
    publishers whose depth discovery did not report (0) get UNKNOWN_DEPTH_REPLAY."""
    if not offers:
        return None
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offers)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offers)
    depth = max(q.depth for q in offers) or UNKNOWN_DEPTH_REPLAY
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                    else DurabilityPolicy.VOLATILE),
    )


def recorded_profile(channel: Any, warn: Callable[[str], None] | None = None
                     ) -> QoSProfile | None:
    """The replay profile of an MCAP channel from its ``offered_qos_profiles`` metadata; None
    when it has none (older recordings, other writers) or they cannot be read (then ``warn``
    gets one line saying why: the caller falls back to the contract's profile)."""
    text = getattr(channel, "metadata", {}).get(QOS_KEY) if channel is not None else None
    if not text:
        return None
    try:
        return replay_profile(parse_offered_qos(text))
    except QosFormatError as e:
        if warn is not None:
            warn(f"{getattr(channel, 'topic', '?')}: recorded {QOS_KEY} unreadable ({e}); "
                 "republished with the contract's profile")
        return None


# --- BagMetadata ---------------------------------------------------------------------------------


@dataclass
class TopicRecord:
    """What the bag metadata says about one recorded topic."""

    name: str
    type_name: str  # 'pkg/msg/Type'
    offered_qos_yaml: str
    type_hash: str = ""
    message_count: int = 0


@dataclass
class BagSummary:
    """Counts and times of a finished recording, to build its BagMetadata from."""

    file_name: str  # relative to the bag (the .mcap file's name)
    topics: list[TopicRecord] = field(default_factory=list)
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def message_count(self) -> int:
        return sum(t.message_count for t in self.topics)


def bag_metadata(summary: BagSummary) -> dict[str, Any]:
    """The BagMetadata (version 9) of a one-file MCAP bag, keys in rosbag2's order. Durations
    and times are nanoseconds; an empty bag starts at 0 with duration 0, as rosbag2's does."""
    start = summary.first_ns or 0
    duration = (summary.last_ns - start) if summary.last_ns is not None else 0
    topics = [{
        "topic_metadata": {
            "name": t.name,
            "type": t.type_name,
            "serialization_format": "cdr",
            # version 9: the list itself (the channel metadata holds it as YAML text)
            "offered_qos_profiles": load_yaml(t.offered_qos_yaml, what=QOS_KEY) or [],
            "type_description_hash": t.type_hash,
        },
        "message_count": t.message_count,
    } for t in summary.topics]
    return {
        "version": BAG_VERSION,
        "storage_identifier": STORAGE_IDENTIFIER,
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": summary.message_count,
        "topics_with_message_count": topics,
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [summary.file_name],
        "files": [{
            "path": summary.file_name,
            "starting_time": {"nanoseconds_since_epoch": start},
            "duration": {"nanoseconds": duration},
            "message_count": summary.message_count,
        }],
        "custom_data": {},
        "ros_distro": ROS_DISTRO,
    }


def serialized_metadata(summary: BagSummary) -> str:
    """The ``serialized_metadata`` value of the ``rosbag2`` MCAP metadata record."""
    return yaml.safe_dump(bag_metadata(summary), sort_keys=False, default_flow_style=False)


def metadata_yaml(summary: BagSummary) -> str:
    """A bag directory's ``metadata.yaml``: the same BagMetadata under its top-level key."""
    return yaml.safe_dump({"rosbag2_bagfile_information": bag_metadata(summary)},
                          sort_keys=False, default_flow_style=False)
