"""Write ROS 2 messages into MCAP as CDR with ``ros2msg`` schemas.

Messages are serialised by rclpy (``serialize_message``), which is the exact CDR a rosbag2
recording holds and orders of magnitude faster than a pure-Python encoder for large payloads.
Chunks are compressed and closed regularly so a crashed writer leaves a file that readers can
open up to the last complete chunk.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, cast

from mcap.writer import CompressionType, Writer
from rclpy.serialization import serialize_message

from sdhn_sim.recording.schema import ros2msg_schema

CHUNK_BYTES = 256 * 1024


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
    """One MCAP file; channels are created on first use of a topic."""

    def __init__(self, path: str | Path, chunk_bytes: int = CHUNK_BYTES) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = _WriteThrough(self.path)
        self._writer = Writer(
            cast(BinaryIO, self._stream), chunk_size=chunk_bytes,
            compression=CompressionType.ZSTD,
        )
        self._writer.start(profile="ros2", library="sdhn")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self.messages_written = 0

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
            channel = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema
            )
            self._channels[topic] = channel
            self._sequence[topic] = 0
        return channel

    def write_serialized(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """Write CDR bytes already serialised by rclpy (a subscription with raw=True)."""
        channel = self._channel(topic, type_name)
        self._writer.add_message(
            channel_id=channel,
            log_time=log_time_ns,
            publish_time=log_time_ns,
            data=data,
            sequence=self._sequence[topic],
        )
        self._sequence[topic] += 1
        self.messages_written += 1

    def write(self, topic: str, message: Any, log_time_ns: int) -> None:
        """Serialise one message object and write it."""
        self.write_serialized(topic, type_name_of(message), serialize_message(message), log_time_ns)

    def close(self) -> None:
        """Finish the file (summary and index); safe to call twice."""
        if not self._stream.closed:
            self._writer.finish()
            self._stream.close()

    def __enter__(self) -> McapRosWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
