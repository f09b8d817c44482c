"""An MCAP recording fed from a queue: the process that holds the messages only appends them; a
writer thread does the MCAP work (records, chunk compression, the graph query for a new topic's
QoS) in batches, so a chunk being compressed never delays the caller.

Shared by the recorder node (messages received over DDS) and the simulator's in-process
recording (``sim recording:=FILE``: the messages it sends and receives), so both write the same
file (:class:`sdhn_sim.recording.writer.McapRosWriter`: schemas, channels, QoS metadata, the
``rosbag2`` record). A write that fails (disk full, file gone) stops the recording: reported once
through ``on_error``, and every later message counted as not written instead of a queue growing
without end.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import QoSProfile

from sdhn_sim.recording.rosbag2 import fill_history, type_hash_text
from sdhn_sim.recording.writer import McapRosWriter

WRITE_PERIOD_S = 0.05  # the writer thread takes the queued messages this often, as one batch

Describe = Callable[[str], tuple[list[QoSProfile], str]]
"""topic -> (offered QoS of every publisher, type hash) for its channel; called on the writer
thread once per topic, before its first message is written."""


def graph_offers(node: Node, topic: str, contract: QoSProfile | None
                 ) -> tuple[list[QoSProfile], str] | None:
    """(offered QoS of every publisher of ``topic``, type hash) from the graph now, as rosbag2
    records them, history and depth filled from ``contract`` (the profile the topic contract
    gives its publishers); None when the graph knows no publisher (gone, or the node is being
    destroyed at shutdown)."""
    try:
        publishers = node.get_publishers_info_by_topic(topic)
    except Exception:  # the node is being destroyed at shutdown
        return None
    if not publishers:
        return None
    return (fill_history([p.qos_profile for p in publishers], contract),
            type_hash_text(publishers[0].topic_type_hash))


class QueuedRecording:
    def __init__(self, path: Path, bag_dir: bool, describe: Describe,
                 on_error: Callable[[str], None]) -> None:
        self.path = path
        self.writer = McapRosWriter(path, bag_dir=bag_dir)
        self.lock = threading.Lock()  # around every write: other writers (viz) may share the file
        self._describe = describe
        self._on_error = on_error
        self._pending: collections.deque[tuple[str, str, bytes, int, int]] = collections.deque()
        self._stop = threading.Event()
        self.batches = 0
        self.largest_batch = 0
        self.error: str | None = None
        self.not_written = 0
        self.writer_cpu_s = 0.0  # CPU time of the writer thread, once it has ended
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._thread.start()

    def put(self, topic: str, type_name: str, data: bytes, log_time_ns: int,
            publish_time_ns: int) -> None:
        """The hot path: queue one message's CDR bytes (written in the order put)."""
        if self.error is not None:
            self.not_written += 1
            return
        self._pending.append((topic, type_name, data, log_time_ns, publish_time_ns))

    @property
    def queue_depth(self) -> int:
        return len(self._pending)

    def _write_loop(self) -> None:
        try:
            while not self._stop.wait(WRITE_PERIOD_S):
                self._write_pending()
            self._write_pending()
            self.writer_cpu_s = time.thread_time()  # this thread's own CPU (a benchmark figure)
        except Exception as e:
            self.error = f"{type(e).__name__}: {e}"
            self._on_error(f"recording stopped, writing {self.path} failed: {self.error}; later "
                           "messages are counted, not written")

    def _write_pending(self) -> None:
        n = len(self._pending)  # only this thread pops; callers only append
        if not n:
            return
        batch = [self._pending.popleft() for _ in range(n)]
        for topic in {m[0] for m in batch}:  # graph queries outside the writer's lock
            if not self.writer.has_channel(topic):
                self.writer.add_topic(topic, *self._describe(topic))
        with self.lock:
            for topic, type_name, data, log_ns, sent_ns in batch:
                self.writer.write_serialized(topic, type_name, data, log_ns, sent_ns)
        self.batches += 1
        self.largest_batch = max(self.largest_batch, n)

    def stop_writing(self) -> None:
        """Write what is queued and end the writer thread (the file stays open)."""
        self._stop.set()
        self._thread.join()

    def close(self) -> int:
        """Finish the file (after ``stop_writing``); the number of messages not written."""
        self.stop_writing()
        with self.lock:
            try:
                self.writer.close()
            except OSError as e:
                self.error = self.error or f"{type(e).__name__}: {e}"
        return len(self._pending) + self.not_written
