"""An actor node that is destroyed is finalised: its rcl node (and with the last one, the DDS
participant) goes while rclpy still runs, not in Fast DDS's static destructor at the process's
exit. rclpy's LifecycleNode kept its state machine, which holds the rcl node, so the participant
outlived rclpy; at exit Fast DDS disabled it there and could deadlock with a departing peer's
discovery callback: actors hung past SIGINT and were killed (a flaky test_decentralised run).

Observable from the graph: another context in this process watches the actor's node name; a
node whose rcl node was never finalised stays in the graph until its participant goes.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest


@pytest.mark.parametrize("managed", [False, True], ids=["unmanaged", "managed"])
def test_a_destroyed_actor_leaves_the_graph_while_its_context_lives(
        weights: Path, managed: bool) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    from sdhn_policy.actor_node import make_actor

    ns = f"/sdhn_teardown_{int(managed)}/robot_0"
    actor_ctx, watch_ctx = Context(), Context()
    args = ["actor", "--ros-args", "-p", "team_ns:=/sdhn_teardown", "-p", "robot_id:=0",
            "-p", "num_robots:=2", "-p", f"weights_file:={weights}",
            "-p", f"managed:={str(managed).lower()}"]
    rclpy.init(args=args, context=actor_ctx, signal_handler_options=SignalHandlerOptions.NO)
    rclpy.init(context=watch_ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        actor = make_actor(actor_ctx, [], namespace=ns)
        watcher = Node("teardown_watcher", context=watch_ctx)

        def listed() -> bool:
            return ("actor", ns) in watcher.get_node_names_and_namespaces()

        def within(seconds: float, condition: bool) -> bool:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                if listed() == condition:
                    return True
                time.sleep(0.05)
            return False

        assert within(20, True), "the actor never appeared in the graph"
        actor.destroy_node()
        assert within(10, False), (
            "the destroyed actor is still in the graph: its rcl node was not finalised")
        watcher.destroy_node()
    finally:
        rclpy.try_shutdown(context=actor_ctx)
        rclpy.try_shutdown(context=watch_ctx)
