"""The recorder node subscribes a robot's ``obs`` only once its ``action`` subscription has matched
that robot's action publisher: the simulator waits for every obs subscriber (``extra_subscribers``
counts the recorder) before step 0, so an actor whose writer had not yet matched the recorder
would lose its first actions from the file. A robot whose actions nobody waits for (no simulator,
e.g. observations played back alone) is not held. Real rclpy nodes, the recorder in one context
(its own DDS participant), the simulator's and actors' endpoints in another."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from sdhn_base.ros import topics
from sdhn_base.ros.qos import STEP
from sdhn_msgs.msg import RobotAction, RobotObservation
from sdhn_sim.recording.recorder_node import DISCOVERY_PERIOD_S, RecorderNode

NS = "/holdobs"


def wait_for(condition: Callable[[], bool], what: str, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"never: {what}"
        time.sleep(0.01)


def topic(i: int, kind: str) -> str:
    return topics.absolute(NS, f"{topics.robot(i)}/{kind}")


@pytest.fixture
def recorder(tmp_path: Path) -> Iterator[RecorderNode]:
    context = Context()
    rclpy.init(args=["--ros-args", "-p", f"output:={tmp_path / 'held.mcap'}", "-p",
                     f"team_ns:={NS}"], context=context)
    node = RecorderNode(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.stop()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        spin.join(timeout=5)


@pytest.fixture
def team() -> Iterator[Node]:
    """The simulator's and actors' side: a node in a context (participant) of its own."""
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("holdobs_team", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_obs_waits_for_the_robots_action_publisher(recorder: RecorderNode, team: Node) -> None:
    # The simulator's endpoints of robots 0 and 1; robot 1's actor is there, robot 0's comes late.
    obs = {i: team.create_publisher(RobotObservation, topic(i, topics.OBS), STEP) for i in (0, 1)}
    for i in (0, 1):
        team.create_subscription(RobotAction, topic(i, topics.ACTION), lambda _m: None, STEP)
    team.create_publisher(RobotAction, topic(1, topics.ACTION), STEP)
    wait_for(lambda: obs[1].get_subscription_count() == 1, "robot_1/obs subscribed")
    wait_for(lambda: team.count_subscribers(topic(0, topics.ACTION)) == 2,
             "robot_0/action subscribed by the recorder")
    time.sleep(3 * DISCOVERY_PERIOD_S)  # rounds in which a recorder that does not hold would
    assert obs[0].get_subscription_count() == 0  # have subscribed robot_0/obs

    action = team.create_publisher(RobotAction, topic(0, topics.ACTION), STEP)
    wait_for(lambda: obs[0].get_subscription_count() == 1, "robot_0/obs subscribed")
    # The simulator would start now: the recorder already has the actor's writer.
    assert recorder._subs[topic(0, topics.ACTION)].get_publisher_count() == 1
    action.publish(RobotAction(robot_id=0))
    wait_for(lambda: recorder.counts[topic(0, topics.ACTION)] == 1, "robot_0's action recorded")


def test_obs_nobody_answers_is_recorded_without_an_action_publisher(
        recorder: RecorderNode, team: Node) -> None:
    # Observations played back alone: no simulator subscribes to robot_2/action.
    obs = team.create_publisher(RobotObservation, topic(2, topics.OBS), STEP)
    wait_for(lambda: obs.get_subscription_count() == 1, "robot_2/obs subscribed")
    obs.publish(RobotObservation(robot_id=2))
    wait_for(lambda: recorder.counts[topic(2, topics.OBS)] == 1, "robot_2's obs recorded")
