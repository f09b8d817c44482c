"""Per-robot actor node (placeholder until the ROS stack lands): starts, logs, stops cleanly."""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.context import Context
from rclpy.node import Node

from sdhn_sim.base_node import run_node


class ActorNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("actor", context=context)
        self.robot_id = int(self.declare_parameter("robot_id", 0).value)
        self.get_logger().info(f"ready: robot_id={self.robot_id}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: ActorNode(context), argv)
