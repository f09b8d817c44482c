"""A two-role peer for the two-process test: ``sim`` sends observations, ``robot`` answers.

Run as ``python peer.py sim --steps N`` and ``python peer.py robot`` in two processes. The sim
re-sends step 0 until the first answer arrives (discovery takes a moment and volatile messages sent
before matching are lost), then runs lock-step: one observation, wait for its action, next step.
The robot answers each observation with action = sum(obs) mod 5. The sim prints one ``OK`` line
with what it received, or exits 1 on a timeout.
"""

from __future__ import annotations

import argparse
import array
import sys
import time

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor

from sdhn_base.ros import topics
from sdhn_base.ros.qos import STEP
from sdhn_msgs.msg import RobotAction, RobotObservation

OBS_1 = topics.absolute("/sdhn", topics.robot_obs(1))
ACTION_1 = topics.absolute("/sdhn", topics.robot_action(1))


def observation(step: int) -> RobotObservation:
    obs = (np.arange(57, dtype=np.float32) * 0.5 + step).astype(np.float32)
    msg = RobotObservation(episode=0, step=step, robot_id=1, num_robots=2)
    msg.obs = array.array("f", obs.tobytes())
    return msg


def run_sim(steps: int, timeout: float) -> int:
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("peer_sim", context=context)
    replies: dict[int, RobotAction] = {}
    pub = node.create_publisher(RobotObservation, OBS_1, STEP)
    node.create_subscription(RobotAction, ACTION_1, lambda m: replies.setdefault(m.step, m), STEP)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    step = 0
    last_sent = 0.0
    while step < steps and time.monotonic() < deadline:
        if step in replies:
            step += 1
            last_sent = 0.0
            continue
        if time.monotonic() - last_sent > (0.2 if step == 0 else 5.0):
            pub.publish(observation(step))
            last_sent = time.monotonic()
        executor.spin_once(timeout_sec=0.01)
    executor.shutdown()
    rclpy.try_shutdown(context=context)
    if step < steps:
        print(f"TIMEOUT after {len(replies)} replies", flush=True)
        return 1
    actions = [replies[s].action for s in range(steps)]
    print(f"OK steps={steps} actions={actions}", flush=True)
    return 0


def run_robot(timeout: float) -> int:
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("peer_robot", context=context)
    pub = node.create_publisher(RobotAction, ACTION_1, STEP)

    def answer(msg: RobotObservation) -> None:
        total = float(np.frombuffer(msg.obs, dtype=np.float32).sum())
        pub.publish(
            RobotAction(
                episode=msg.episode, step=msg.step, robot_id=msg.robot_id, action=int(total) % 5
            )
        )

    node.create_subscription(RobotObservation, OBS_1, answer, STEP)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    executor.shutdown()
    rclpy.try_shutdown(context=context)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=["sim", "robot"])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--timeout", type=float, default=20.0)
    args = parser.parse_args()
    return run_sim(args.steps, args.timeout) if args.role == "sim" else run_robot(args.timeout)


if __name__ == "__main__":
    sys.exit(main())
