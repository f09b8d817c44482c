"""Write ROS 2 messages into MCAP as CDR with ``ros2msg`` schemas, as rosbag2 (Jazzy) writes them.

Messages are serialised by rclpy (``serialize_message``), which is the exact CDR a rosbag2
recording holds and orders of magnitude faster than a pure-Python encoder for large payloads.
Chunks are compressed and closed regularly so a crashed writer leaves a file that readers can
open up to the last complete chunk.

rosbag2 compatibility (:mod:`sdhn_sim.recording.rosbag2`): every channel carries the
``offered_qos_profiles`` of its topic's publishers (given by ``add_topic`` before the first message;
a topic written without it says ``[]``, and ``ros2 bag play`` then uses its defaults) and its
``topic_type_hash``; each message has log time (receive), publish time (send) and a per-channel
sequence number counting from 1; a clean close adds the ``rosbag2`` metadata record (the whole
BagMetadata), and ``bag_dir=True`` also writes the bag directory's ``metadata.yaml``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, cast

from mcap.writer import CompressionType, Writer
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message

from sdhn_sim.recording import rosbag2
from sdhn_sim.recording.schema import ros2msg_schema

CHUNK_BYTES = 256 * 1024
NO_TIME_YET = 2**63  # above any log time (uint64 nanoseconds < 2**64, ours < 2**63)


def type_name_of(message: Any) -> str:
    """'sdhn_msgs/msg/RobotAction' for an instance of that message class."""
    module = type(message).__module__  # e.g. sdhn_msgs.msg._robot_action
    package = module.split(".", 1)[0]
    return f"{package}/msg/{type(message).__name__}"


class _WriteThrough:
    """A file whose every write reaches the OS at once. The MCAP writer keeps messages in its
    chunk builder and writes only whole records (the header, then each finished chunk and its
    index), so this costs a few flushes per chunk; without it the header and the end of the last
    finished chunk sat in Python's buffer, and a recorder killed before its first 8 KiB left an
    empty file (not even MCAP magic) and one killed later lost the chunk it had just finished."""

    def __init__(self, path: Path) -> None:
        self._file = open(path, "wb")  # noqa: SIM115 - closed in close()

    def write(self, data: bytes) -> int:
        n = self._file.write(data)
        self._file.flush()
        return n

    def tell(self) -> int:
        return self._file.tell()

    def flush(self) -> None:
        self._file.flush()

    @property
    def closed(self) -> bool:
        return self._file.closed

    def close(self) -> None:
        self._file.close()


class McapRosWriter:
    """One MCAP file; channels are created on first use of a topic. With ``bag_dir=True`` the
    file is the one storage file of a rosbag2 bag directory (its parent), and a clean close
    writes that directory's ``metadata.yaml`` too."""

    def __init__(self, path: str | Path, chunk_bytes: int = CHUNK_BYTES,
                 bag_dir: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.bag_dir = bag_dir
        self._stream = _WriteThrough(self.path)
        self._writer = Writer(
            cast(BinaryIO, self._stream), chunk_size=chunk_bytes,
            compression=CompressionType.ZSTD,
        )
        self._writer.start(profile="ros2", library="sdhn")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._topics: dict[str, rosbag2.TopicRecord] = {}  # in order of first message
        self._declared: dict[str, tuple[str, str]] = {}  # topic -> (QoS YAML, type hash)
        self._first_ns = NO_TIME_YET  # log times seen so far (min, max)
        self._last_ns = -1
        self.messages_written = 0

    def add_topic(self, topic: str, offered_qos: Sequence[QoSProfile], type_hash: str = ""
                  ) -> None:
        """What the channel of ``topic`` will say about its publishers (before its first
        message; later calls for a topic that has its channel change nothing)."""
        if topic not in self._channels:
            self._declared[topic] = (rosbag2.offered_qos_yaml(offered_qos), type_hash)

    def has_channel(self, topic: str) -> bool:
        return topic in self._channels

    @property
    def mcap(self) -> Writer:
        """The underlying ``mcap`` writer, to add channels of other encodings (viz.channels)."""
        return self._writer

    def _channel(self, topic: str, type_name: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(type_name)
            if schema is None:
                schema = self._writer.register_schema(
                    name=type_name, encoding="ros2msg", data=ros2msg_schema(type_name).encode()
                )
                self._schemas[type_name] = schema
            qos_yaml, type_hash = self._declared.pop(topic, (rosbag2.offered_qos_yaml([]), ""))
            channel = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema,
                metadata={rosbag2.QOS_KEY: qos_yaml, rosbag2.TYPE_HASH_KEY: type_hash},
            )
            self._channels[topic] = channel
            self._sequence[topic] = 0
            self._topics[topic] = rosbag2.TopicRecord(topic, type_name, qos_yaml, type_hash)
        return channel

    def write_serialized(self, topic: str, type_name: str, data: bytes, log_time_ns: int,
                         publish_time_ns: int | None = None) -> None:
        """Write CDR bytes already serialised by rclpy (a subscription with raw=True):
        ``log_time_ns`` when it was received, ``publish_time_ns`` when it was sent (default: the
        log time, for a message that was never on the wire)."""
        channel = self._channel(topic, type_name)
        sequence = self._sequence[topic] + 1  # also the topic's message count
        self._sequence[topic] = sequence
        self._writer.add_message(
            channel_id=channel,
            log_time=log_time_ns,
            publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
            data=data,
            sequence=sequence,
        )
        # comparisons, not min()/max(): measurably cheaper per message on the hot path
        if log_time_ns < self._first_ns:  # noqa: PLR1730
            self._first_ns = log_time_ns
        if log_time_ns > self._last_ns:  # noqa: PLR1730
            self._last_ns = log_time_ns
        self.messages_written += 1

    def write(self, topic: str, message: Any, log_time_ns: int) -> None:
        """Serialise one message object and write it."""
        self.write_serialized(topic, type_name_of(message), serialize_message(message), log_time_ns)

    def bag_summary(self) -> rosbag2.BagSummary:
        """The counts and times of what was written so far (the BagMetadata's source)."""
        for topic, record in self._topics.items():
            record.message_count = self._sequence[topic]
        if not self.messages_written:
            return rosbag2.BagSummary(self.path.name, list(self._topics.values()))
        return rosbag2.BagSummary(self.path.name, list(self._topics.values()), self._first_ns,
                                  self._last_ns)

    def close(self) -> None:
        """Finish the file (the ``rosbag2`` metadata record, summary and index; with
        ``bag_dir``, then ``metadata.yaml`` beside it, atomically); safe to call twice."""
        if self._stream.closed:
            return
        summary = self.bag_summary()
        self._writer.add_metadata(rosbag2.METADATA_RECORD, {
            "serialized_metadata": rosbag2.serialized_metadata(summary),
            "ros_distro": rosbag2.ROS_DISTRO,
        })
        self._writer.finish()
        self._stream.close()
        if self.bag_dir:
            target = self.path.parent / "metadata.yaml"
            tmp = target.with_name(f".metadata.yaml.{os.getpid()}.w.tmp")  # sdhn_base.litter
            tmp.write_text(rosbag2.metadata_yaml(summary))
            os.replace(tmp, target)

    def __enter__(self) -> McapRosWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
