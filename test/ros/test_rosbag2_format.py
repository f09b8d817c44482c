"""The recorder writes what rosbag2 (Jazzy) writes, so ``ros2 bag play`` replays with the right QoS:
read back with the plain ``mcap`` reader and ``yaml`` (never through our own reader), every part is
checked against rosbag2's format: header profile, ``ros2msg`` schemas, per-channel
``offered_qos_profiles`` equal to the publishers' QoS and ``topic_type_hash``, the ``rosbag2``
metadata record (the whole BagMetadata, version 9), sequences and times; the bag-directory option
writes a ``metadata.yaml`` that rosbags opens."""

from __future__ import annotations

import re
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from mcap.reader import make_reader
from rclpy.qos import QoSProfile
from rosbags.highlevel import AnyReader

from sdhn_base.ros import topics
from sdhn_base.ros.qos import LATCHED, SENSOR, STEP

from .own_node import own_node
from .processes import ROS2, node_processes
from .team_stream import hypergraph_message, team_stream, weights_message

NS = "/bagtest"
QOS_KEYS = ["history", "depth", "reliability", "durability", "deadline", "lifespan",
            "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions"]
BAG_KEYS = {"version": int, "storage_identifier": str, "duration": dict, "starting_time": dict,
            "message_count": int, "topics_with_message_count": list, "compression_format": str,
            "compression_mode": str, "relative_file_paths": list, "files": list,
            "custom_data": dict, "ros_distro": str}
POLICY = re.compile(r"^(system_default|keep_last|keep_all|reliable|best_effort|transient_local|"
                    r"volatile|automatic|manual_by_topic|unknown|best_available)$")


@dataclass
class Bag:
    path: Path
    profile: dict[str, QoSProfile]  # topic -> the profile its publisher used
    output: str  # the recorder's output


def record(output: Path) -> Bag:
    """Publish a short 4-robot stream with the contract's profiles while a recorder records."""
    msgs = list(team_stream(1, 6))
    from sdhn_msgs.msg import Hypergraph, PolicyWeights

    types = {o.topic: type(o.message) for o in msgs}
    profile = {topics.absolute(NS, t): STEP for t in types}
    profile[topics.absolute(NS, topics.WEIGHTS)] = LATCHED
    profile[topics.absolute(NS, topics.HYPERGRAPH)] = SENSOR
    command = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={output}",
               "-p", f"team_ns:={NS}"]
    with own_node("bag_test_publisher") as node:
        pubs = {t: node.create_publisher(cls, topics.absolute(NS, t), STEP)
                for t, cls in types.items()}
        weights = node.create_publisher(PolicyWeights, topics.absolute(NS, topics.WEIGHTS), LATCHED)
        graphs = node.create_publisher(Hypergraph, topics.absolute(NS, topics.HYPERGRAPH), SENSOR)
        weights.publish(weights_message(1))
        with node_processes(command) as (recorder,):
            assert recorder.wait_for_line("ready", timeout=30), recorder.output
            deadline = time.monotonic() + 20
            every = [*pubs.values(), weights, graphs]
            while any(p.get_subscription_count() == 0 for p in every):
                assert time.monotonic() < deadline, f"recorder never subscribed:\n{recorder.output}"
                time.sleep(0.05)
            for o in msgs:
                pubs[o.topic].publish(o.message)
            for k in range(3):
                graphs.publish(hypergraph_message(k))
                time.sleep(0.02)
            for p in [*pubs.values(), weights]:
                assert p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
            time.sleep(0.3)
            assert recorder.stop(timeout=10.0) == 0, recorder.output
            line = next(x for x in recorder.lines if "ready: recording" in x)
    path = Path(line.split(" to ", 1)[1].split(" ", 1)[0].rstrip(";"))
    return Bag(path, profile, str(output))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bag]:
    yield record(tmp_path_factory.mktemp("bag") / "run.mcap")


@dataclass
class Parsed:
    profile: str
    schemas: dict[int, Any]
    channels: dict[int, Any]
    messages: list[tuple[Any, Any]]  # (channel, message)
    metadata: list[Any]


def parse(path: Path) -> Parsed:
    with path.open("rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None, "no summary section: the file was not finished"
        messages = [(channel, message) for _, channel, message in reader.iter_messages()]
        metadata = list(reader.iter_metadata())
    return Parsed(header.profile, dict(summary.schemas), dict(summary.channels), messages,
                  metadata)


def test_header_schemas_and_channels_are_rosbag2s(bag: Bag) -> None:
    p = parse(bag.path)
    assert p.profile == "ros2"
    for schema in p.schemas.values():
        assert schema.encoding == "ros2msg", schema.name
        assert re.fullmatch(r"\w+/msg/\w+", schema.name), schema.name
    assert {c.topic for c in p.channels.values()} == set(bag.profile), "every published topic"
    for channel in p.channels.values():
        assert channel.message_encoding == "cdr", channel.topic
        assert set(channel.metadata) == {"offered_qos_profiles", "topic_type_hash"}, \
            channel.metadata


def test_channel_qos_is_what_the_publisher_offered(bag: Bag) -> None:
    for channel in parse(bag.path).channels.values():
        offers = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        assert isinstance(offers, list) and len(offers) == 1, (channel.topic, offers)
        offer = offers[0]
        assert list(offer) == QOS_KEYS, f"{channel.topic}: keys {list(offer)}"
        for key in ("history", "reliability", "durability", "liveliness"):
            assert isinstance(offer[key], str) and POLICY.match(offer[key]), (key, offer[key])
        for key in ("deadline", "lifespan", "liveliness_lease_duration"):
            assert list(offer[key]) == ["sec", "nsec"], (key, offer[key])
            assert all(isinstance(v, int) for v in offer[key].values())
        assert isinstance(offer["depth"], int) and isinstance(
            offer["avoid_ros_namespace_conventions"], bool)
        want = bag.profile[channel.topic]
        assert offer["reliability"] == want.reliability.name.lower(), (channel.topic, offer)
        assert offer["durability"] == want.durability.name.lower(), (channel.topic, offer)
        assert (offer["history"], offer["depth"]) == ("keep_last", want.depth), \
            (channel.topic, offer)
        hash_text = channel.metadata["topic_type_hash"]
        assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", hash_text), (channel.topic, hash_text)


def test_rosbag2_metadata_record_is_the_whole_bag_metadata(bag: Bag) -> None:
    p = parse(bag.path)
    records = [m for m in p.metadata if m.name == "rosbag2"]
    assert len(records) == 1, [m.name for m in p.metadata]
    assert set(records[0].metadata) == {"serialized_metadata", "ros_distro"}
    assert records[0].metadata["ros_distro"] == "jazzy"
    meta = yaml.safe_load(records[0].metadata["serialized_metadata"])
    assert list(meta) == list(BAG_KEYS), list(meta)
    for key, kind in BAG_KEYS.items():
        assert isinstance(meta[key], kind), (key, meta[key])
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    counts = Counter(c.topic for c, _ in p.messages)
    assert meta["message_count"] == len(p.messages)
    log_times = [m.log_time for _, m in p.messages]
    assert meta["starting_time"] == {"nanoseconds_since_epoch": min(log_times)}
    assert meta["duration"] == {"nanoseconds": max(log_times) - min(log_times)}
    assert meta["relative_file_paths"] == [bag.path.name]
    assert meta["files"] == [{"path": bag.path.name, "starting_time": meta["starting_time"],
                              "duration": meta["duration"], "message_count": len(p.messages)}]
    by_topic = {c.topic: c for c in p.channels.values()}
    listed = {}
    for entry in meta["topics_with_message_count"]:
        t = entry["topic_metadata"]
        assert list(t) == ["name", "type", "serialization_format", "offered_qos_profiles",
                           "type_description_hash"], list(t)
        channel = by_topic[t["name"]]
        assert t["type"] == p.schemas[channel.schema_id].name
        assert t["serialization_format"] == "cdr"
        # version 9: a list here, the same list as YAML text in the channel
        assert t["offered_qos_profiles"] == yaml.safe_load(
            channel.metadata["offered_qos_profiles"])
        assert t["type_description_hash"] == channel.metadata["topic_type_hash"]
        listed[t["name"]] = entry["message_count"]
    assert listed == dict(counts)


def test_sequences_count_and_times_are_monotone_per_channel(bag: Bag) -> None:
    by_channel: dict[str, list[Any]] = {}
    for channel, message in parse(bag.path).messages:
        by_channel.setdefault(channel.topic, []).append(message)
    for topic, messages in by_channel.items():
        messages.sort(key=lambda m: m.sequence)
        assert [m.sequence for m in messages] == list(range(1, len(messages) + 1)), topic
        logs = [m.log_time for m in messages]
        assert logs == sorted(logs), f"{topic}: log times not in sequence order"
        for m in messages:
            # publish time: never after receipt (the recorder writes the receive time there:
            # the events executor cannot pass it the send time; docs/recording.md)
            assert 0 < m.publish_time <= m.log_time, (topic, m.publish_time, m.log_time)


def test_bag_directory_has_metadata_yaml_that_rosbags_opens(tmp_path: Path) -> None:
    bag = record(tmp_path / "bagdir")
    assert bag.path == tmp_path / "bagdir" / "bagdir_0.mcap"
    meta = yaml.safe_load((tmp_path / "bagdir" / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    record_meta = next(m for m in parse(bag.path).metadata if m.name == "rosbag2")
    assert info == yaml.safe_load(record_meta.metadata["serialized_metadata"])
    with AnyReader([tmp_path / "bagdir"]) as reader:  # rosbags reads metadata.yaml first
        counts = Counter(c.topic for c, _, _ in reader.messages())
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert sum(counts.values()) == info["message_count"]
    weights = topics.absolute(NS, topics.WEIGHTS)
    assert len(qos[weights]) == 1, qos[weights]
    assert "transient_local" in str(qos[weights][0].durability).lower(), qos[weights]
