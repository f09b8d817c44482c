"""Recorder node ``sdhn_sim recorder``: every topic under ``team_ns`` into one MCAP file.

Messages are taken as raw CDR (subscriptions with ``raw=True``, no deserialisation) and written
with ``ros2msg`` schemas by :class:`sdhn_sim.recording.writer.McapRosWriter`, as rosbag2 writes
them (log time = receive time; publish time, which rosbag2 takes from the message info's send
time, is the receive time too: see ``on_message``), each channel with its publishers' offered QoS
and type hash, and the ``rosbag2`` metadata record at the end (docs/recording.md).

The recorder must not slow the loop it records: it is its own process with its own executor, and
its callbacks only append (topic, type, bytes, times) to a queue; a writer thread
(:class:`sdhn_sim.recording.queued.QueuedRecording`, which the simulator's in-process recording
shares) takes the queue in batches and does the MCAP work off the executor thread.

Which topics, with which QoS:
- The contract's topics are subscribed from the start, with their contract profile, so nothing
  published before the next discovery round is missed: ``state``, ``episode`` (STEP),
  ``policy/weights`` (LATCHED_RECORDER: the latest version is received even if it was published
  before the recorder started, and versions published back to back are all kept), ``hypergraph``
  (SENSOR). As soon as any ``robot_<i>/...`` topic is seen (a publisher *or* a subscriber, e.g.
  the trainer's), both ``robot_<i>/action`` and ``robot_<i>/obs`` are subscribed (STEP), before
  that robot's first message. The simulator starts step 0 only when every obs topic has all its
  subscribers (``extra_subscribers`` counts the recorder), and each actor subscribes to its
  observations only once its action writer has matched every reader of its actions
  (``action_readers``, which counts the recorder where the launcher starts it): so the recorder
  has every robot's actions from step 0. Actors not told of the recorder (started by hand with
  the default ``action_readers``) can lose their first actions from the file: matching is per
  side, and this node cannot see whether a writer has matched it.
- Any other topic under ``team_ns`` is found by discovery every ``DISCOVERY_PERIOD_S`` and
  subscribed with the named profile that matches its publishers (transient-local ->
  LATCHED_RECORDER, best-effort -> SENSOR, else STEP); a topic with no publisher yet waits for the
  next round.
- Not recorded: the standard viewer topics ``poses`` and ``robot_<i>/target_pose``
  (:func:`derived`). They are computed from what is recorded (TeamState positions, observations
  and actions), and the simulator and actors publish them only while someone subscribes: a
  recorder subscribing would make every actor build and send one more message per step.

Offered QoS: when a topic's first message is written, its channel gets the QoS of every
publisher the graph knows for it (``get_publishers_info_by_topic``, as rosbag2 records it), with
history and depth, which DDS discovery does not carry, from the profile the contract gives that
topic's publishers (``CONTRACT_TOPICS``, ``ROBOT_TOPICS``; other topics say unknown, 0, as in
rosbag2). A publisher already gone by then is described by the contract's profile or, for a
discovered topic, by what discovery saw.

One file per run: an existing ``output`` is never overwritten (``-1``, ``-2``... is appended).
``output`` ending in ``.mcap`` is a bare MCAP file (``ros2 bag play FILE.mcap``); any other path
is a rosbag2 bag directory holding ``<name>_0.mcap`` and, after a clean stop, ``metadata.yaml``.
The file is finalised (summary, index) on SIGINT/SIGTERM; a crash leaves it readable up to the
last complete chunk (``sdhn_sim replay`` says where it stops).

Viz channels (parameter ``viz``, default true): the team's ``state``, ``hypergraph`` and
``episode`` messages are also turned into the viz node's Foxglove channels (``/viz/scene``,
``/viz/hypergraph``, ``/viz/hypergraph/p_h``, ``/viz/metrics``, ``/viz/episodes``; protobuf and
JSON, see ``sdhn_sim.viz.channels``) in the same file, so a recording opens as pictures. The
subscription callback only queues the raw CDR (a few microseconds); a worker thread deserialises,
renders and writes (under the writer's lock), each viz message with its source's log time. If the
worker falls ``VIZ_QUEUE`` messages behind, viz for the newest is skipped and counted: the raw
recording always comes first, and ``replay --add-viz`` can rebuild the viz from a ``viz:=false``
recording.

Once a second the recorder reports on ``/diagnostics`` (``sdhn_base.diagnostics``): messages
waiting for the writer thread, messages not written (a failed write), viz messages skipped or
dropped by cause. It does not record ``/diagnostics`` itself (not under ``team_ns``).
"""

from __future__ import annotations

import functools
import queue
import threading
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from sdhn_base.diagnostics import ERROR, OK, Report, WindowCounts, drop_values, make_report
from sdhn_base.drops import DropKind
from sdhn_base.ros import topics
from sdhn_base.ros.diagnostics import DiagnosticsPublisher
from sdhn_base.ros.params import boolean, declare, string
from sdhn_base.ros.qos import LATCHED, LATCHED_RECORDER, SENSOR, STEP
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_sim.recording.queued import QueuedRecording, graph_offers
from sdhn_sim.recording.reader import fresh_path
from sdhn_sim.recording.rosbag2 import type_hash_text
from sdhn_sim.recording.schema import UnknownMessageType, message_class, ros2msg_schema
from sdhn_sim.viz.channels import KINDS, VizDeriver, VizMcapChannels

DISCOVERY_PERIOD_S = 0.5
VIZ_QUEUE = 2000  # team messages waiting for the viz worker before viz is skipped
STATUS_PERIOD_S = 5.0
CONTRACT_TOPICS = {  # relative to team_ns: (type, the recorder's profile, the publisher's)
    topics.STATE: ("sdhn_msgs/msg/TeamState", STEP, STEP),
    topics.EPISODE: ("sdhn_msgs/msg/EpisodeSummary", STEP, STEP),
    topics.WEIGHTS: ("sdhn_msgs/msg/PolicyWeights", LATCHED_RECORDER, LATCHED),
    topics.HYPERGRAPH: ("sdhn_msgs/msg/Hypergraph", SENSOR, SENSOR),
}
ROBOT_TOPICS = {
    topics.OBS: "sdhn_msgs/msg/RobotObservation",
    topics.ACTION: "sdhn_msgs/msg/RobotAction",
}
PARAMETERS = {
    "output": ("", string("the .mcap file to write, or a rosbag2 bag directory (a path not "
                          "ending in .mcap); '' = runs/recording-<time>.mcap (an existing file "
                          "or directory is never overwritten: -1, -2... is appended)")),
    "team_ns": (topics.DEFAULT_TEAM_NS, string(f"team namespace; {topics.TEAM_NS_RULE}")),
    # Off by default: rosbags (and other ROS-only readers) cannot open a file that also holds
    # protobuf channels. `replay --add-viz` makes a Foxglove copy of a plain recording.
    "viz": (False, boolean("also write the /viz/* channels (Foxglove) into the file")),
}


def derived(relative: str) -> bool:
    """A standard viewer topic computed from recorded ones (not recorded)."""
    return relative == topics.POSES or relative.rsplit("/", 1)[-1] == topics.TARGET_POSE


def profile_for(publisher_qos: list[QoSProfile]) -> QoSProfile:
    """The named profile a subscriber needs to match all of these publishers."""
    if publisher_qos and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                             for q in publisher_qos):
        return LATCHED_RECORDER
    if any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in publisher_qos):
        return SENSOR
    return STEP


class VizWorker:
    """Derives the viz channels from queued raw team messages on its own thread."""

    def __init__(self, channels: VizMcapChannels, lock: threading.Lock) -> None:
        self.channels = channels
        self.lock = lock
        self.deriver = VizDeriver()
        self.queue: queue.Queue[tuple[str, str, bytes, int] | None] = queue.Queue(VIZ_QUEUE)
        self.skipped = 0
        self.error: str | None = None
        self.busy_s: dict[str, float] = {}  # per kind, the first message (warm-up) excluded
        self.timed: Counter[str] = Counter()
        self.thread = threading.Thread(target=self.run, name="viz", daemon=True)
        self.thread.start()

    def offer(self, kind: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """The hot path: queue the message, or count it as skipped when the worker is behind."""
        try:
            self.queue.put_nowait((kind, type_name, data, log_time_ns))
        except queue.Full:
            self.skipped += 1

    def run(self) -> None:
        while (item := self.queue.get()) is not None:
            kind, type_name, data, log_time_ns = item
            t0 = time.thread_time()  # CPU of this thread: waits for the GIL do not count
            try:
                msg = deserialize_message(data, message_class(type_name))
            except Exception:  # malformed CDR: counted like any message that cannot be drawn
                self.deriver.dropped[f"{kind}/{DropKind.UNDECODABLE}"] += 1
                continue
            try:
                out = self.deriver.derive(kind, msg, log_time_ns)
                with self.lock:
                    self.channels.write(out)
            except Exception as e:  # a bug here must never stop the raw recording
                self.error = f"{type(e).__name__}: {e}"
                return
            finally:
                self.timed[kind] += 1
                if self.timed[kind] > 1:  # the first of a kind loads instance sets: warm-up
                    self.busy_s[kind] = self.busy_s.get(kind, 0.0) + time.thread_time() - t0

    def stop(self) -> None:
        """Finish what is queued (bounded by VIZ_QUEUE) and end the thread."""
        if self.thread.is_alive():
            self.queue.put(None)
            self.thread.join()

    def summary(self) -> str:
        written = sum(self.deriver.written.values())
        cost = "".join(f", {self.busy_s[k] / (self.timed[k] - 1) * 1e3:.2f} ms per {k}"
                       for k in sorted(self.timed) if self.timed[k] > 1)
        dropped = ", ".join(f"{k}={v}" for k, v in sorted(self.deriver.dropped.items()))
        return (f"viz: {written} messages{cost}; skipped (worker behind) {self.skipped}; "
                f"dropped {dropped or 'none'}"
                + (f"; STOPPED by {self.error}" if self.error else ""))


class RecorderNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("recorder", context=context)
        p = declare(self, PARAMETERS)
        output, viz = str(p["output"]), bool(p["viz"])
        self.ns = topics.check_team_ns(p["team_ns"])
        requested = Path(output or f"runs/recording-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
        bag_dir = requested.suffix != ".mcap"
        if bag_dir and not requested.name.strip("."):
            raise ConfigError(f"output: {output!r}; allowed: a path ending in .mcap, or a bag "
                              "directory to create")
        where = fresh_path(requested)
        self.path = where / f"{where.name}_0.mcap" if bag_dir else where
        self.recording = QueuedRecording(self.path, bag_dir, self.describe,
                                         self.get_logger().error)
        self.writer = self.recording.writer
        self.lock = self.recording.lock  # the viz worker writes into the same MCAP writer
        self.viz = (VizWorker(VizMcapChannels(self.writer.mcap), self.lock) if viz else None)
        self._viz_kinds = {topics.absolute(self.ns, kind): kind for kind in KINDS.values()}
        self.counts: dict[str, int] = {}
        self.skipped: set[str] = set()
        self._publisher_qos: dict[str, QoSProfile] = {}  # topic -> the contract's profile
        self._discovered: dict[str, tuple[list[QoSProfile], str]] = {}  # topic -> as seen
        self._subs: dict[str, Any] = {}
        self._robots: set[int] = set()
        self._t0 = time.monotonic()
        self._bytes = 0
        self._last_status = ""
        for rel, (type_name, profile, offered) in CONTRACT_TOPICS.items():
            self.record(topics.absolute(self.ns, rel), type_name, profile, offered)
        self.discover()
        self.create_timer(DISCOVERY_PERIOD_S, self.discover)
        self.create_timer(STATUS_PERIOD_S, self.log_status)
        self._drops_window = WindowCounts()
        self.diagnostics = DiagnosticsPublisher(self, self.diagnostics_report)
        note = "" if where == requested else f" ({requested} exists)"
        note += "" if viz else "; no viz channels (viz:=false)"
        self.get_logger().info(f"ready: recording {self.ns}/* to {self.path}{note}")

    def record(self, topic: str, type_name: str, profile: QoSProfile,
               offered: QoSProfile | None = None) -> None:
        """Subscribe to ``topic`` (raw CDR) unless already done or impossible (logged once);
        ``offered``: the contract's publisher profile, written when the graph cannot say."""
        if topic in self._subs or topic in self.skipped:
            return
        try:
            cls = message_class(type_name)
            ros2msg_schema(type_name)  # the schema must be writable too
        except (UnknownMessageType, ValueError, FileNotFoundError) as e:
            self.skipped.add(topic)
            self.get_logger().warning(f"not recording {topic} ({type_name}): {e}")
            return
        self._subs[topic] = self.create_subscription(
            cls, topic, functools.partial(self.on_message, topic, type_name), profile, raw=True)
        self.counts[topic] = 0
        if offered is not None:
            self._publisher_qos[topic] = offered

    def discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            rel = topics.relative_to(self.ns, topic)
            if rel is None or topic in self._subs or topic in self.skipped or derived(rel):
                continue
            robot = topics.robot_of(rel)
            if robot and robot[0] not in self._robots:
                i = robot[0]
                self._robots.add(i)
                for kind in (topics.ACTION, topics.OBS):
                    self.record(topics.absolute(self.ns, f"{topics.robot(i)}/{kind}"),
                                ROBOT_TOPICS[kind], STEP, STEP)
                if topic in self._subs:
                    continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers or len(types) != 1:
                continue  # nobody publishes yet (or ambiguous types): next round
            offers = [p.qos_profile for p in publishers]
            self._discovered[topic] = (offers, type_hash_text(publishers[0].topic_type_hash))
            self.record(topic, types[0], profile_for(offers))

    def describe(self, topic: str) -> tuple[list[QoSProfile], str]:
        """(offered QoS of every publisher, type hash) for ``topic``'s channel: from the graph
        now, as rosbag2 does; else what discovery saw, else the contract's publisher profile.
        Called on the writer thread (rclpy's graph queries take the node's lock)."""
        contract = self._publisher_qos.get(topic)
        found = graph_offers(self, topic, contract)
        if found is not None:
            return found
        if topic in self._discovered:
            return self._discovered[topic]
        return ([contract] if contract is not None else []), ''

    def on_message(self, topic: str, type_name: str, data: bytes) -> None:
        # time.time_ns() is the ROS system clock without rclpy's ~17 us per call (no sim time here)
        now = time.time_ns()
        # Publish time = receive time: the send time is in the message info, which the events
        # executor of these wheels cannot pass (a two-argument callback raises SystemError
        # there), and the default executor would cost several times the CPU per message.
        self.recording.put(topic, type_name, data, now, now)  # the writer thread writes it
        if self.viz is not None and (kind := self._viz_kinds.get(topic)) is not None:
            self.viz.offer(kind, type_name, data, now)
        self.counts[topic] += 1
        self._bytes += len(data)

    def log_status(self) -> None:
        elapsed = max(time.monotonic() - self._t0, 1e-9)
        total = self.writer.messages_written
        line = (f"status: {total} messages ({self._bytes / 1e6:.2f} MB) on "
                f"{sum(1 for c in self.counts.values() if c)} topics, "
                f"{total / elapsed:.0f} msg/s")
        if line.split(",", maxsplit=1)[0] != self._last_status.split(",", maxsplit=1)[0]:
            self._last_status = line
            self.get_logger().info(line)

    def diagnostics_report(self) -> Report:
        drops: dict[str, int] = {}
        if self.viz is not None:
            drops = {f"viz/{k}": v for k, v in self.viz.deriver.dropped.items()}
            drops["viz/skipped_worker_behind"] = self.viz.skipped
        values: dict[str, float | int | str] = {
            "messages_written": self.writer.messages_written,
            "write_queue_depth": self.recording.queue_depth,
            "not_written": self.recording.not_written,
            "topics": sum(1 for c in self.counts.values() if c), "file": str(self.path),
        }
        values |= drop_values(drops, self._drops_window.new(drops))
        error = self.recording.error
        note = f"writing stopped: {error}" if error else ""
        return make_report(self.get_fully_qualified_name(), self.ns, values,
                           ("write_queue_depth", "not_written", "dropped_in_window"), note,
                           floor=ERROR if error else OK)

    def stop(self) -> None:
        self.recording.stop_writing()
        if self.viz is not None:
            self.viz.stop()
        lost = self.recording.close()
        if self.recording.error is not None:
            self.get_logger().error(f"recording incomplete ({self.recording.error}); {lost} "
                                    "messages not written")
        per_topic = ", ".join(f"{t}={c}" for t, c in sorted(self.counts.items()) if c)
        self.get_logger().info(f"closed {self.path}: {self.writer.messages_written} messages "
                               f"({self._bytes / 1e6:.2f} MB) in {self.recording.batches} "
                               f"batches (largest {self.recording.largest_batch}); "
                               f"{per_topic}")
        if self.viz is not None:
            self.get_logger().info(self.viz.summary())


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: RecorderNode(context), argv,
                    on_stop=lambda node: node.stop() if isinstance(node, RecorderNode) else None)
