"""Recorder node ``sdhn_sim recorder``: every topic under ``team_ns`` into one MCAP file.

Messages are taken as raw CDR (subscriptions with ``raw=True``, no deserialisation) and written
with ``ros2msg`` schemas by :class:`sdhn_sim.mcap_writer.McapRosWriter`; log time = receive time.

Which topics, with which QoS:
- The contract's topics are subscribed from the start, with their contract profile, so nothing
  published before the next discovery round is missed: ``state``, ``episode`` (STEP),
  ``policy/weights`` (LATCHED: the latest version is received even if it was published before the
  recorder started), ``hypergraph`` (SENSOR). As soon as any ``robot_<i>/...`` topic is seen (a
  publisher *or* a subscriber, e.g. the trainer's), both ``robot_<i>/obs`` and
  ``robot_<i>/action`` are subscribed (STEP), before that robot's first message.
- Any other topic under ``team_ns`` is found by discovery every ``DISCOVERY_PERIOD_S`` and
  subscribed with the named profile that matches its publishers (transient-local -> LATCHED,
  best-effort -> SENSOR, else STEP); a topic with no publisher yet waits for the next round.

One file per run: an existing ``output`` is never overwritten (``-1``, ``-2``... is appended).
The file is finalised (summary, index) on SIGINT/SIGTERM; a crash leaves it readable up to the
last complete chunk (``sdhn_sim replay`` says where it stops).
"""

from __future__ import annotations

import functools
import importlib
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from sdhn_sim.base_node import ConfigError, run_node
from sdhn_sim.mcap_schema import ros2msg_schema
from sdhn_sim.mcap_writer import McapRosWriter
from sdhn_sim.qos import LATCHED, SENSOR, STEP

DISCOVERY_PERIOD_S = 0.5
STATUS_PERIOD_S = 5.0
CONTRACT_TOPICS = {  # relative to team_ns: (type, profile)
    "state": ("sdhn_msgs/msg/TeamState", STEP),
    "episode": ("sdhn_msgs/msg/EpisodeSummary", STEP),
    "policy/weights": ("sdhn_msgs/msg/PolicyWeights", LATCHED),
    "hypergraph": ("sdhn_msgs/msg/Hypergraph", SENSOR),
}
ROBOT_TOPICS = {
    "obs": "sdhn_msgs/msg/RobotObservation",
    "action": "sdhn_msgs/msg/RobotAction",
}
_ROBOT = re.compile(r"^robot_(\d+)/")


def message_class(type_name: str) -> Any:
    """'pkg/msg/Type' -> the Python message class; ImportError/AttributeError if unknown."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def profile_for(publisher_qos: list[QoSProfile]) -> QoSProfile:
    """The named profile a subscriber needs to match all of these publishers."""
    if publisher_qos and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                             for q in publisher_qos):
        return LATCHED
    if any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in publisher_qos):
        return SENSOR
    return STEP


def fresh_path(path: Path) -> Path:
    """``path`` if it does not exist yet, else ``<stem>-1<suffix>``, ``-2``... (never clobber)."""
    if not path.exists():
        return path
    k = 1
    while (candidate := path.with_name(f"{path.stem}-{k}{path.suffix}")).exists():
        k += 1
    return candidate


class RecorderNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("recorder", context=context)
        output = self.declare_parameter("output", "").value
        team_ns = self.declare_parameter("team_ns", "/sdhn").value
        if not isinstance(output, str):
            raise ConfigError(f"output: {output!r}; allowed: a path of a .mcap file, or '' "
                              "(runs/recording-<time>.mcap)")
        if not isinstance(team_ns, str) or not team_ns.startswith("/"):
            raise ConfigError(f"team_ns: {team_ns!r}; allowed: an absolute namespace like /sdhn")
        requested = Path(output or f"runs/recording-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
        if requested.suffix != ".mcap":
            raise ConfigError(f"output: {output!r}; allowed: a path ending in .mcap")
        self.path = fresh_path(requested)
        self.ns = team_ns.rstrip("/")
        self.writer = McapRosWriter(self.path)
        self.counts: dict[str, int] = {}
        self.skipped: set[str] = set()
        self._subs: dict[str, Any] = {}
        self._robots: set[int] = set()
        self._t0 = time.monotonic()
        self._bytes = 0
        self._last_status = ""
        for rel, (type_name, profile) in CONTRACT_TOPICS.items():
            self.record(f"{self.ns}/{rel}", type_name, profile)
        self.discover()
        self.create_timer(DISCOVERY_PERIOD_S, self.discover)
        self.create_timer(STATUS_PERIOD_S, self.log_status)
        note = "" if self.path == requested else f" ({requested} exists)"
        self.get_logger().info(f"ready: recording {self.ns}/* to {self.path}{note}")

    def record(self, topic: str, type_name: str, profile: QoSProfile) -> None:
        """Subscribe to ``topic`` (raw CDR) unless already done or impossible (logged once)."""
        if topic in self._subs or topic in self.skipped:
            return
        try:
            cls = message_class(type_name)
            ros2msg_schema(type_name)  # the schema must be writable too
        except (ImportError, AttributeError, ValueError, FileNotFoundError) as e:
            self.skipped.add(topic)
            self.get_logger().warning(f"not recording {topic} ({type_name}): {e}")
            return
        self._subs[topic] = self.create_subscription(
            cls, topic, functools.partial(self.on_message, topic, type_name), profile, raw=True)
        self.counts[topic] = 0

    def discover(self) -> None:
        prefix = self.ns + "/"
        for topic, types in self.get_topic_names_and_types():
            if not topic.startswith(prefix) or topic in self._subs or topic in self.skipped:
                continue
            rel = topic[len(prefix):]
            robot = _ROBOT.match(rel)
            if robot and int(robot.group(1)) not in self._robots:
                i = int(robot.group(1))
                self._robots.add(i)
                for kind, type_name in ROBOT_TOPICS.items():
                    self.record(f"{prefix}robot_{i}/{kind}", type_name, STEP)
                if topic in self._subs:
                    continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers or len(types) != 1:
                continue  # nobody publishes yet (or ambiguous types): next round
            self.record(topic, types[0], profile_for([p.qos_profile for p in publishers]))

    def on_message(self, topic: str, type_name: str, data: bytes) -> None:
        # time.time_ns() is the ROS system clock without rclpy's ~17 us per call (no sim time here)
        self.writer.write_serialized(topic, type_name, data, time.time_ns())
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

    def stop(self) -> None:
        self.writer.close()
        per_topic = ", ".join(f"{t}={c}" for t, c in sorted(self.counts.items()) if c)
        self.get_logger().info(f"closed {self.path}: {self.writer.messages_written} messages "
                               f"({self._bytes / 1e6:.2f} MB); {per_topic}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: RecorderNode(context), argv,
                    on_stop=lambda node: node.stop() if isinstance(node, RecorderNode) else None)
