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


def message_class(type_name: str) -> Any:
    """The Python class of ``pkg/msg/Type`` (or ``pkg/Type``), as rosidl_runtime_py's
    ``get_message`` finds it; ValueError with one line if the install has no such type."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    # The name comes from the graph or the command line: import only a package's ``msg``
    # interfaces module, never an arbitrary module path.
    if len(parts) != 3 or parts[1] != "msg" or not all(p.isidentifier() for p in parts):
        raise ValueError(f"message type: {type_name!r}; expected pkg/msg/Type")
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
        return getattr(module, parts[2])
    except (ImportError, AttributeError) as e:
        raise ValueError(f"message type {type_name!r} is not installed here") from e


def absolute_name(name: str) -> str:
    """A topic or node name as the graph spells it (a leading slash)."""
    return name if name.startswith("/") else "/" + name


def split_node_name(full: str) -> tuple[str, str]:
    """('/ns/sub', 'node') of '/ns/sub/node'; ('/', 'node') of 'node' or '/node'."""
    full = absolute_name(full)
    ns, _, name = full.rpartition("/")
    return ns or "/", name
