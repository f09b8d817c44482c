"""Trainer node (placeholder until the ROS stack lands): starts, logs, stops cleanly."""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.context import Context
from rclpy.node import Node

from sdhn_sim.base_node import run_node


class TrainerNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("trainer", context=context)
        self.env_name = self.declare_parameter("env", "maif-10").value
        self.get_logger().info(f"ready: env={self.env_name}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: TrainerNode(context), argv)
