"""``replay --rate`` republishes every topic with the QoS recorded for it (the channel's
``offered_qos_profiles``), not by topic name: a late-joining process still gets the latest
``policy/weights`` (transient-local, depth 1), and a topic recorded latched or best effort under
any name is republished so."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from sdhn_base.ros import topics
from sdhn_base.ros.qos import LATCHED, SENSOR, STEP
from sdhn_sim.recording.writer import McapRosWriter

from .own_node import own_node
from .processes import ROS2, node_processes
from .team_stream import weights_message

NS = "/replayqos"
SPAN_S = 12  # recorded seconds: the replay lives this long at rate 1
LATE = """
import sys, time, rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from sdhn_msgs.msg import PolicyWeights
from sdhn_base.ros.qos import LATCHED
c = Context(); rclpy.init(context=c)
n = rclpy.create_node("late_joiner", context=c)
ex = SingleThreadedExecutor(context=c); ex.add_node(n)
got = []
n.create_subscription(PolicyWeights, sys.argv[1], lambda m: got.append(m.version), LATCHED)
deadline = time.monotonic() + 20
while not got and time.monotonic() < deadline:
    ex.spin_once(timeout_sec=0.1)
time.sleep(0.3); ex.spin_once(timeout_sec=0.1)
print("VERSIONS", got, flush=True)
ex.shutdown()
n.destroy_node(); rclpy.try_shutdown(context=c)
"""
# A topic the contract does not name, recorded latched: only its QoS metadata says so.
CUSTOM_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=3,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)


def write_recording(path: Path) -> dict[str, QoSProfile]:
    """Weights v1 and v2 at the start, then a state-like string every second for SPAN_S s."""
    weights = topics.absolute(NS, topics.WEIGHTS)
    recorded = {weights: LATCHED, f"{NS}/notes": CUSTOM_LATCHED, f"{NS}/samples": SENSOR,
                f"{NS}/log": STEP}
    t0 = time.time_ns()
    with McapRosWriter(path) as w:
        for topic, profile in recorded.items():
            w.add_topic(topic, [profile])
        w.write(weights, weights_message(1), t0)
        w.write(weights, weights_message(2), t0 + 1_000_000)
        w.write(f"{NS}/notes", String(data="latched note"), t0 + 2_000_000)
        for k in range(SPAN_S):
            t = t0 + 10_000_000 + k * 1_000_000_000
            w.write(f"{NS}/samples", String(data=f"sample {k}"), t)
            w.write(f"{NS}/log", String(data=f"log {k}"), t + 1000)
    return recorded


def test_replay_republishes_every_topic_with_its_recorded_qos(tmp_path: Path) -> None:
    path = tmp_path / "qos.mcap"
    recorded = write_recording(path)
    weights = topics.absolute(NS, topics.WEIGHTS)
    replay = [*ROS2, "run", "sdhn_sim", "replay", str(path), "--rate", "1", "--wait", "0"]
    with own_node("replay_qos_observer") as node, node_processes(replay) as (player,):
        deadline = time.monotonic() + 30
        while not all(node.get_publishers_info_by_topic(t) for t in recorded):
            assert player.proc.poll() is None, player.output
            assert time.monotonic() < deadline, f"replay never published:\n{player.output}"
            time.sleep(0.05)
        # Started after the replay published the weights: only transient-local delivers them.
        late = subprocess.run([sys.executable, "-c", LATE, weights], capture_output=True,
                              text=True, timeout=60, check=False)
        offered = {t: node.get_publishers_info_by_topic(t)[0].qos_profile for t in recorded}
        assert player.proc.poll() is None, "the replay ended before the late joiner asked"
        player.stop()
    assert "VERSIONS [2]" in late.stdout, (late.stdout, late.stderr)
    for topic, want in recorded.items():
        got = offered[topic]
        assert (got.reliability, got.durability) == (want.reliability, want.durability), \
            f"{topic}: republished {got.reliability.name}/{got.durability.name}, recorded " \
            f"{want.reliability.name}/{want.durability.name}"
