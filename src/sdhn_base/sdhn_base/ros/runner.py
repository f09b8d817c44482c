"""The one ``main`` loop every sdhn node runs: init, build the node, spin, stop cleanly.

Why not ``rclpy.spin``: the events executor of the Jazzy wheels busy-loops and ignores signals
when spun without a timeout (docs/ros-graph.md), so we spin in short slices. SIGINT and SIGTERM
set a flag instead of rclpy's own handler shutting the context down under us, so the node can
still log and flush (``on_stop``) before it is destroyed; the exit code is then 0. A node that
finds it cannot do its job sets ``failed_reason`` (:data:`FAILED`): exit code 1 and that line. A
configuration error found while building the node exits with code 2 and one line on stderr,
before any topic is created. Once the node is built, the ready file of :mod:`sdhn_base.ros.status`
is written (when asked for).

Teardown is bounded: once ``on_stop`` has run, destroying the node, shutting the context down and
leaving the interpreter get :data:`TEARDOWN_S` seconds. Past that, a C-level watchdog
(``faulthandler``, which needs no GIL, so a DDS deadlock that holds it cannot stop it) prints every
thread's Python stack and ends the process with exit code 1. Why: a Fast DDS teardown deadlock
(participant removal racing a departing peer, eProsima/Fast-DDS #6502, #6193) has been seen to keep
an actor alive after SIGINT, which hangs whoever stops it.
"""

from __future__ import annotations

import faulthandler
import gc
import signal
import sys
import threading
from collections.abc import Callable, Sequence

import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from sdhn_base.errors import ConfigError
from sdhn_base.litter import clean_fastdds_shm
from sdhn_base.ros import topics
from sdhn_base.ros.params_file import (
    ParamsFileError,
    check_params_file,
    params_files,
    unknown_parameters,
)
from sdhn_base.ros.status import write_ready

SPIN_SLICE_S = 0.05
# A node that cannot go on sets this attribute to a one-line reason: the loop stops, the reason
# goes to stderr and the exit code is 1 (the launcher reports the child as failed).
FAILED = "failed_reason"
TEARDOWN_S = 5.0


MAX_ERROR_CHARS = 500


def one_line(text: str) -> str:
    """``text`` as one line of about ``MAX_ERROR_CHARS`` characters at most, its start (the
    field) and its end (what is allowed) kept: a parameter value of 50 MB was echoed whole into
    the 'one line' error."""
    flat = " ".join(text.split())
    if len(flat) <= MAX_ERROR_CHARS:
        return flat
    head, tail = MAX_ERROR_CHARS * 3 // 5, MAX_ERROR_CHARS * 2 // 5
    return f"{flat[:head]} [... {len(flat) - head - tail} characters ...] {flat[-tail:]}"


def run_node(
    make_node: Callable[[Context, list[str]], Node | Sequence[Node]],
    argv: Sequence[str] | None = None,
    on_stop: Callable[[Node], None] | None = None,
) -> int:
    """Run one node (or several, on one executor: ``make_node`` may return a sequence, as the
    actor host does) until SIGINT/SIGTERM or ``context.shutdown()``; returns the exit code.

    ``make_node`` receives the context and the command-line arguments with ROS arguments removed.
    ``on_stop`` runs before each node is destroyed (flush files, stop worker threads).
    It is a process's main: after it returns the process has ``TEARDOWN_S`` seconds to exit.
    """
    args = list(sys.argv if argv is None else argv)
    prog = args[0] if args else "node"
    clean_fastdds_shm()  # what killed participants left in /dev/shm (sdhn_base.litter)
    try:  # before rcl: a file it cannot parse was a 23-line traceback from rclpy.init
        for path in params_files(args):
            check_params_file(path)
    except ParamsFileError as error:
        print(f"{prog}: error: {one_line(str(error))}", file=sys.stderr)
        return 2
    context = Context()
    try:
        rclpy.init(args=args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # rcl's RCLError: whatever else it refuses in the ROS arguments
        first = (str(error).strip().splitlines() or [type(error).__name__])[0]
        print(f"{prog}: error: ROS arguments: {first[:300]}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    nodes: list[Node] = []
    try:
        try:
            made = make_node(context, rclpy.utilities.remove_ros_args(args)[1:])
        except (ConfigError, topics.NamespaceError) as error:
            print(f"{prog}: error: {one_line(str(error))}", file=sys.stderr)
            return 2
        nodes = [made] if isinstance(made, Node) else list(made)
        node = nodes[0]
        for each in nodes:
            unknown = unknown_parameters(list(each._parameter_overrides),
                                         list(each._parameters))
            if unknown:  # a misspelt name did nothing, silently
                shown = ", ".join(n[:60] for n in unknown[:10])
                more = f" and {len(unknown) - 10} more" if len(unknown) > 10 else ""
                each.get_logger().warning(
                    f"unknown parameters {shown}{more}: this node does not declare them "
                    "(misspelt?); they have no effect")
        # Everything built so far (imports: rclpy, NumPy, torch in the trainer) lives as long as
        # the process: keep it out of the garbage collector's full passes, which otherwise walk
        # it all and stall the callbacks (hundreds of ms with torch imported, on a busy machine).
        gc.collect()
        gc.freeze()
        executor = EventsExecutor(context=context)
        for each in nodes:
            executor.add_node(each)
        write_ready(node.get_name(), node.get_namespace())

        def failed() -> str:
            return next((r for r in (getattr(n, FAILED, "") for n in nodes) if r), "")

        try:
            while context.ok() and not stop.is_set() and not failed():
                executor.spin_once(timeout_sec=SPIN_SLICE_S)
        finally:
            executor.shutdown(timeout_sec=1.0)
        reason = failed()
        if reason:
            print(f"{prog}: error: {reason}", file=sys.stderr)
            return 1
        return 0
    finally:
        for each in nodes:
            if on_stop is not None:
                on_stop(each)
            each.get_logger().info("stopped")
        # Not cancelled: it also bounds the interpreter's exit, where rclpy's objects are freed.
        faulthandler.dump_traceback_later(TEARDOWN_S, exit=True)
        for each in nodes:
            each.destroy_node()
        rclpy.try_shutdown(context=context)
        # Finalise the rmw context now (it deletes the DDS participant once the executor and
        # node let go, at the latest when this frame returns). Left to the process's exit, Fast
        # DDS's static factory destructor disables the participant itself and was seen to spin
        # there for over 10 s under load, after Python (and this watchdog) had finished. That
        # only happens if a node's rcl node was never finalised (rclpy's LifecycleNode keeps it
        # through its state machine: ActorNode.destroy_node; test/ros/test_actor_teardown.py).
        context.destroy()
