"""A talker for the ``ros2`` verb tests: ``python graph_peer.py NS PERIOD_S``.

Node ``NS/graph_peer`` publishes ``NS/peer/obs`` (RobotObservation, STEP: reliable, volatile)
every PERIOD_S with step k and obs = k + 0.25 * arange(57) (float32), and once, latched,
``NS/peer/note`` (std_msgs/String, LATCHED: reliable, transient-local) with text ``hello NS``.
It reports itself on stdout, so the tests compare the tools' output with what the node knows:
one ``QOS <topic> <reliability> <durability> <depth>`` line per publisher at start, then
``SENT <step>`` per message. Stops on SIGINT/SIGTERM.
"""

from __future__ import annotations

import array
import signal
import sys

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import String

from sdhn_base.ros.qos import LATCHED, STEP
from sdhn_msgs.msg import RobotObservation


def observation(step: int) -> RobotObservation:
    obs = (step + 0.25 * np.arange(57)).astype(np.float32)
    msg = RobotObservation(episode=1, step=step, robot_id=0, num_robots=1, reward=0.5)
    msg.obs = array.array("f", obs.tobytes())
    return msg


def main() -> int:
    ns, period = sys.argv[1], float(sys.argv[2])
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("graph_peer", namespace=ns, context=context)
    obs_pub = node.create_publisher(RobotObservation, f"{ns}/peer/obs", STEP)
    note_pub = node.create_publisher(String, f"{ns}/peer/note", LATCHED)
    for topic, qos in ((f"{ns}/peer/obs", STEP), (f"{ns}/peer/note", LATCHED)):
        print(f"QOS {topic} {qos.reliability.name} {qos.durability.name} {qos.depth}", flush=True)
    note_pub.publish(String(data=f"hello {ns}"))
    step = 0

    def tick() -> None:
        nonlocal step
        obs_pub.publish(observation(step))
        print(f"SENT {step}", flush=True)
        step += 1

    node.create_timer(period, tick)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: context.try_shutdown())
    while context.ok():
        executor.spin_once(timeout_sec=0.05)
    return 0


if __name__ == "__main__":
    sys.exit(main())
