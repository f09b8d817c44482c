"""The thin ROS half of :mod:`sdhn_base.diagnostics`: one ``diagnostic_msgs/DiagnosticArray`` per
second on ``/diagnostics`` (the standard topic, absolute: every node of every team shares it, as
ROS's diagnostic aggregator expects). ``diagnostic_updater`` has no wheel; this is the part of it
we need.

    self.diagnostics = DiagnosticsPublisher(self, self.diagnostics_report)  # in __init__

The report callback runs on the node's executor once per period and must be cheap (it reads
counters the node keeps anyway).
"""

from __future__ import annotations

from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from sdhn_base.diagnostics import PERIOD_S, Report
from sdhn_base.ros import topics
from sdhn_base.ros.qos import DIAGNOSTICS


def to_status(report: Report) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=bytes([report.level]), name=report.name, message=report.message,
        hardware_id=report.hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in report.key_values()])


class DiagnosticsPublisher:
    """Publishes ``report()`` on ``/diagnostics`` every :data:`PERIOD_S` seconds."""

    def __init__(self, node: Node, report: Callable[[], Report],
                 period_s: float = PERIOD_S) -> None:
        self.node = node
        self.report = report
        self.pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, DIAGNOSTICS)
        self.timer = node.create_timer(period_s, self.publish)

    def publish(self) -> None:
        msg = DiagnosticArray(status=[to_status(self.report())])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(msg)
