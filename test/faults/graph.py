"""Fault-test tools that run in the test process: a watcher node that timestamps what the graph
publishes, graph introspection, the launcher as a child process, and ROS log-line parsing.

The watcher never subscribes to ``robot_<i>/obs``: the simulator counts obs subscribers before
step 0, and an extra one from the test would let it start before the trainer or recorder is up.
"""

from __future__ import annotations

import os
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ros.processes import NodeProcess

from sdhn_base.ros import topics

LAUNCH = [sys.executable, "-m", "sdhn_bringup"]
_LOG_TIME = re.compile(r"^\[(\w+)\] \[(\d+\.\d+)\] \[([^\]]+)\]: (.*)$")


@dataclass
class Received:
    t: float  # time.time() when the watcher got it
    msg: Any


@dataclass
class Seen:
    states: list[Received] = field(default_factory=list)
    actions: dict[int, list[Received]] = field(default_factory=dict)
    weights: list[Received] = field(default_factory=list)
    episodes: list[Received] = field(default_factory=list)

    def versions(self) -> list[int]:
        return [int(r.msg.version) for r in self.weights]

    def latest_version(self) -> int:
        return max(self.versions(), default=0)


class Peer:
    """An rclpy node of the test process: create its topics, then ``start()`` spins it on a
    background thread (callbacks run there); ``close()`` always."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.02)

    def topics(self) -> dict[str, list[str]]:
        return dict(self.node.get_topic_names_and_types())

    def close(self) -> None:
        import rclpy

        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Watcher(Peer):
    """Subscribes to state, episode, policy/weights and every action topic; ``seen`` fills up as
    messages arrive, each with its receive time."""

    def __init__(self, ns: str, num_robots: int, name: str = "fault_watcher") -> None:
        from sdhn_base.ros.qos import LATCHED, STEP
        from sdhn_msgs.msg import EpisodeSummary, PolicyWeights, RobotAction, TeamState

        super().__init__(name)
        self.ns = ns.rstrip("/")
        self.seen = Seen()
        node = self.node
        def name(relative: str) -> str:
            return topics.absolute(self.ns, relative)

        self.subs = [node.create_subscription(TeamState, name(topics.STATE),
                                              _add(self.seen.states), STEP),
                     node.create_subscription(EpisodeSummary, name(topics.EPISODE),
                                              _add(self.seen.episodes), STEP),
                     node.create_subscription(PolicyWeights, name(topics.WEIGHTS),
                                              _add(self.seen.weights), LATCHED)]
        for i in range(num_robots):
            self.seen.actions[i] = []
            self.subs.append(node.create_subscription(
                RobotAction, name(topics.robot_action(i)), _add(self.seen.actions[i]), STEP))
        self.start()


def _add(into: list[Received]) -> Callable[[Any], None]:
    def callback(msg: Any) -> None:
        into.append(Received(time.time(), msg))
    return callback


@contextmanager
def watching(ns: str, num_robots: int) -> Iterator[Watcher]:
    w = Watcher(ns, num_robots)
    try:
        yield w
    finally:
        w.close()


# --- launcher -----------------------------------------------------------------------------------


def launch_cmd(run_dir: Path, *sets: str, config: str | None = None) -> list[str]:
    args = [*LAUNCH, *([config] if config else []), "--set", f"run_dir={run_dir}",
            "--set", "status_interval=1.0"]
    for item in sets:
        args += ["--set", item]
    return args


TRAIN_TINY = ("env=maif-tiny", "mode=train", "episodes=0", "recorder=false",
              "restart.policy=on-failure", "restart.max_restarts=5", "max_steps=25",
              "step_deadline=0.5", "trainer.rollout_steps=16")


def pids(launcher: NodeProcess) -> dict[str, int]:
    """Current pid of every child, from the launcher's 'pids:' and 'restarted' lines."""
    out: dict[str, int] = {}
    for line in list(launcher.lines):
        if "pids:" in line:
            out.update({k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", line)})
        m = re.search(r"restarted (\w+) \(\d+/\d+\), pid (\d+)", line)
        if m:
            out[m.group(1)] = int(m.group(2))
    return out


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not reaped yet) counts as dead
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


@dataclass(frozen=True)
class LogLine:
    severity: str
    t: float  # wall-clock seconds, as rcutils stamps it
    logger: str
    text: str


def log_lines(path: Path) -> list[LogLine]:
    """The rcutils-formatted lines of a child's log file (other lines are skipped)."""
    try:
        raw = path.read_text(errors="replace").splitlines()
    except OSError:
        return []
    out = []
    for line in raw:
        m = _LOG_TIME.match(line)
        if m:
            out.append(LogLine(m.group(1), float(m.group(2)), m.group(3), m.group(4)))
    return out
