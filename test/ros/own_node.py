"""A node of the test's own in the test process: in an rclpy context of its own (so it never
shares init state with another test or with a node under test), and always torn down, executor
first, then the node, then the context, even when the test fails half-way through its set-up.

    with own_node("rec_test_publisher") as node: ...                # publishes only
    with own_node_and_executor("test_observer") as (node, executor): ...  # also spins
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rclpy.executors import Executor
    from rclpy.node import Node


@contextmanager
def own_node(name: str) -> Iterator[Node]:
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node(name, context=context)
        try:
            yield node
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@contextmanager
def own_node_and_executor(name: str, make_executor: Callable[..., Executor] | None = None
                          ) -> Iterator[tuple[Node, Executor]]:
    """The node added to an executor of its context (``make_executor(context=...)``, by default
    rclpy's SingleThreadedExecutor; rclpy.experimental's EventsExecutor fits too)."""
    from rclpy.executors import SingleThreadedExecutor

    with own_node(name) as node:
        make: Callable[..., Any] = make_executor or SingleThreadedExecutor
        executor = make(context=node.context)
        executor.add_node(node)
        try:
            yield node, executor
        finally:
            executor.shutdown(timeout_sec=1.0)
