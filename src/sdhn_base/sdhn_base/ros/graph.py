"""A short-lived rclpy node for the ``ros2`` verbs (topic, node, param): what ros2cli's direct
(no-daemon) node does.

ros2cli asks its daemon, which has watched the graph since it started; without a daemon it spins
its own node for ``--spin-time`` (0.5 s by default) before reading the graph, so that discovery
has a chance to see the others. This node does the same, with the same hidden name pattern
(``_ros2cli_<pid>``), so it does not show in ``ros2 node list`` of anyone.

    with GraphNode(spin_time_s=0.5) as g:
        names = g.node.get_topic_names_and_types()
"""

from __future__ import annotations

import importlib
import os
import re
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from sdhn_base.litter import clean_fastdds_shm

DEFAULT_SPIN_TIME_S = 0.5  # ros2cli's --spin-time default without a daemon
# A node or topic named on the command line may not be discovered yet after the spin time (no
# daemon has watched the graph before): it is looked for this long before it counts as absent.
NAMED_WAIT_S = 5.0


T = TypeVar("T")


class GraphNode:
    """An rclpy context, a hidden node and an executor; ``spin`` waits for discovery."""

    def __init__(self, spin_time_s: float = DEFAULT_SPIN_TIME_S, name: str = "") -> None:
        self.spin_time_s = spin_time_s
        self.name = name or f"_ros2cli_{os.getpid()}"
        self.context = Context()
        self.node: Node
        self.executor: SingleThreadedExecutor

    def __enter__(self) -> GraphNode:
        # As every node of ours does (ros.runner): segments that killed participants left in
        # /dev/shm make Fast DDS print port errors on stdout, into the tool's output.
        clean_fastdds_shm()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(self.name, context=self.context,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spin(self.spin_time_s)
        return self

    def spin(self, seconds: float) -> None:
        """Serve callbacks (and let discovery run) for ``seconds``."""
        end = time.monotonic() + seconds
        while self.context.ok():
            left = end - time.monotonic()
            if left <= 0:
                return
            try:
                self.executor.spin_once(timeout_sec=min(0.05, left))
            except ExternalShutdownException:  # Ctrl-C or --once ended the context: done
                return

    def wait_for(self, found: Callable[[], T], seconds: float = NAMED_WAIT_S) -> T:
        """``found()`` once it is truthy, spinning meanwhile; its last value after ``seconds``."""
        end = time.monotonic() + seconds
        value = found()
        while not value and time.monotonic() < end and self.context.ok():
            self.spin(0.1)
            value = found()
        return value

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# The interface packages whose messages this project's graphs carry: ours, the standard streams
# our nodes publish beside them (geometry_msgs poses and target poses, diagnostic_msgs
# /diagnostics, lifecycle_msgs transition events of managed actors), /rosout and
# /parameter_events that every rclpy node has (rcl_interfaces), and std_msgs. A type name comes
# from the command line or from the graph, where any participant may advertise any name: it only
# ever selects one of these, so outside input never decides which module is imported.
GRAPH_MESSAGE_PACKAGES = ("sdhn_msgs", "std_msgs", "geometry_msgs", "diagnostic_msgs",
                          "lifecycle_msgs", "rcl_interfaces")
# ROS 2 interface naming rules (REP 144 packages, CamelCase types).
_PACKAGE = re.compile(r"[a-z][a-z0-9_]*")
_TYPE = re.compile(r"[A-Z][A-Za-z0-9]*")


def check_message_type(type_name: str, field: str = "message type") -> tuple[str, str]:
    """('pkg', 'Type') of ``pkg/msg/Type`` (or ``pkg/Type``) whose package is one of
    :data:`GRAPH_MESSAGE_PACKAGES`; ValueError with one line naming ``field``, the value and
    what is allowed otherwise. Imports nothing."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if (len(parts) != 3 or parts[1] != "msg" or not _PACKAGE.fullmatch(parts[0])
            or not _TYPE.fullmatch(parts[2])):
        raise ValueError(f"{field}: {type_name!r} is not a message type; expected pkg/msg/Type")
    if parts[0] not in GRAPH_MESSAGE_PACKAGES:
        raise ValueError(f"{field}: {type_name!r} is in package {parts[0]!r}, not one this "
                         f"project's graphs carry; allowed: {', '.join(GRAPH_MESSAGE_PACKAGES)}")
    return parts[0], parts[2]


def message_class(type_name: str, field: str = "message type") -> Any:
    """The Python class of ``pkg/msg/Type`` (or ``pkg/Type``) in one of
    :data:`GRAPH_MESSAGE_PACKAGES`, as rosidl_runtime_py's ``get_message`` finds it; ValueError
    with one line for a name :func:`check_message_type` refuses (before any import) or a type
    the install does not have."""
    package, name = check_message_type(type_name, field)
    # The module name is the allowlist's own string, never one built from the input.
    allowed = GRAPH_MESSAGE_PACKAGES[GRAPH_MESSAGE_PACKAGES.index(package)]
    try:
        module = importlib.import_module(f"{allowed}.msg")
    except ImportError as e:
        raise ValueError(f"{field}: {type_name!r} is not installed here") from e
    cls = getattr(module, name, None)
    if not isinstance(cls, type):
        raise ValueError(f"{field}: {type_name!r} is not installed here ({allowed} has no "
                         f"message {name!r})")
    return cls


def absolute_name(name: str) -> str:
    """A topic or node name as the graph spells it (a leading slash)."""
    return name if name.startswith("/") else "/" + name


def split_node_name(full: str) -> tuple[str, str]:
    """('/ns/sub', 'node') of '/ns/sub/node'; ('/', 'node') of 'node' or '/node'."""
    full = absolute_name(full)
    ns, _, name = full.rpartition("/")
    return ns or "/", name
