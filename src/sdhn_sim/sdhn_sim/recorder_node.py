"""Recorder node (placeholder until the ROS stack lands): starts, logs, stops cleanly."""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.context import Context
from rclpy.node import Node

from sdhn_sim.base_node import run_node


class RecorderNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("recorder", context=context)
        self.output = self.declare_parameter("output", "runs/recording.mcap").value
        self.get_logger().info(f"ready: output={self.output}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: RecorderNode(context), argv)
