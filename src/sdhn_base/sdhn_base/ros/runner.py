"""The one ``main`` loop every sdhn node runs: init, build the node, spin, stop cleanly.

Why not ``rclpy.spin``: the events executor of the Jazzy wheels busy-loops and ignores signals
when spun without a timeout (docs/ros-graph.md), so we spin in short slices. SIGINT and SIGTERM
set a flag instead of rclpy's own handler shutting the context down under us, so the node can
still log and flush (``on_stop``) before it is destroyed; the exit code is then 0. A node that
finds it cannot do its job sets ``failed_reason`` (:data:`FAILED`): exit code 1 and that line. A
configuration error found while building the node exits with code 2 and one line on stderr,
before any topic is created. Once the node is built, the ready file of :mod:`sdhn_base.ros.status`
is written (when asked for).

How the process ends once a node was built and stopped (the loop ended by SIGINT/SIGTERM,
``context.shutdown()`` or FAILED, with no exception): ``on_stop`` runs and "stopped" is logged,
then the nodes are destroyed (their publishers, subscriptions and services leave the graph at
once), the context is shut down (rcl's logging finalised: the ROS log file is complete), the
non-daemon threads joined, the ``atexit`` handlers run (Python logging's flush; rclpy registers
none) and stdout/stderr flushed, and the process ends with ``os._exit`` and its exit code. The
DDS participant is never deleted: a hidden node (``_sdhn_exiting_<pid>``) created for that
holds it until the process is gone (after a ``context.shutdown()`` no node can be created, so the
stopped nodes are left undestroyed too). Why: deleting it can deadlock in Fast DDS 2.14 (eProsima/
Fast-DDS #6502, #6193). ``destroy_participant`` first sets the participant's listener to null,
which waits until no discovery callback is in flight, while a UDP receive thread is in one
(``onWriterDiscovery``: a departing peer's writer removed, e.g. the simulator that has just
stopped) waiting on a mutex, and the event and shared-memory threads wait on the discovery
(PDP) mutex. gdb showed actors stuck there about once in ~270 teardowns of the test suite
(after they had logged "stopped"), ended by the watchdog below with exit code 1: a failed child
to the launcher. No ordering of ours removes the race (any peer may leave, or be dropped by its
lease, at any time); not deleting the participant does. Moving the deletion from Fast DDS's
static destructor at exit into this runner (an earlier fix) had only bounded it.

What that changes: peers drop the participant when its lease ends (Fast DDS's default
``leaseDuration``, 20 s) instead of on its goodbye, as for a killed process. Until then the
hidden ``_sdhn_exiting_<pid>`` node (and ``/parameter_events`` writer) is in their graph, not
the stopped node, whose endpoints were destroyed. The participant's shared-memory segment
(``/dev/shm/fastrtps_<id>``) is left as a killed process leaves it; the next node's start
removes it (:func:`sdhn_base.litter.clean_fastdds_shm`). Nothing else is deleted at exit:
finalizers and destructors do not run, so a node's ``on_stop`` must close what it owns (files,
recorders, servers, child processes). test/ros/test_node_exit.py holds this.

The other ends keep the previous teardown: a configuration error (exit code 2, the node never
built), or an exception out of the loop or ``on_stop`` (a traceback, exit code 1) destroy the
nodes and the context. Teardown is bounded on every path: once ``on_stop`` has run, what
follows gets :data:`TEARDOWN_S` seconds. Past that, a C-level watchdog (``faulthandler``, which
needs no GIL, so a DDS deadlock that holds it cannot stop it) prints every thread's Python stack
and ends the process with exit code 1.
"""

from __future__ import annotations

import atexit
import contextlib
import faulthandler
import gc
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import NoReturn

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException
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
# A node may set this integer attribute: the exit code when it stopped without failing (the
# simulator's: 1 when not every actor matched in time).
EXIT_CODE = "exit_code"
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
    actor host does) until SIGINT/SIGTERM or ``context.shutdown()``, then end the process.

    ``make_node`` receives the context and the command-line arguments with ROS arguments removed.
    ``on_stop`` runs before each node is destroyed: it must close everything the node owns
    (files, worker threads, child processes), since no destructor runs after it.
    It is a process's main. Once a node was built and stopped it does not return: the process
    ends with exit code 0, a node's :data:`EXIT_CODE`, or 1 (:data:`FAILED`), without deleting
    the DDS participant (module docstring). It returns 2 on a configuration error found before
    (the caller exits with it); an exception propagates after the previous teardown.
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
    code = 1
    stopped_cleanly = False  # the loop ended (stop, shutdown or FAILED), no exception
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
                try:
                    executor.spin_once(timeout_sec=SPIN_SLICE_S)
                except ExternalShutdownException:
                    break  # context.shutdown() in a callback: a stop, as SIGTERM is
        finally:
            executor.shutdown(timeout_sec=1.0)
        reason = failed()
        if reason:
            print(f"{prog}: error: {reason}", file=sys.stderr)
            code = 1
        else:
            code = next((c for c in (getattr(n, EXIT_CODE, 0) for n in nodes) if c), 0)
        stopped_cleanly = True
        return code
    finally:
        for each in nodes:
            if on_stop is not None:
                on_stop(each)
            each.get_logger().info("stopped")
        # Not cancelled: it also bounds the interpreter's exit, where rclpy's objects are freed.
        faulthandler.dump_traceback_later(TEARDOWN_S, exit=True)
        if nodes and stopped_cleanly:
            _leave_keeping_participant(context, nodes, code)  # does not return
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


def _leave_keeping_participant(context: Context, nodes: Sequence[Node], code: int) -> NoReturn:
    """End the process with ``code`` after its nodes stopped, without deleting the DDS
    participant (the module docstring says why).

    The nodes are destroyed (their publishers, subscriptions and services leave the graph at
    once, as before) while a hidden node created here keeps the participant; the context is shut
    down, which finalises rcl's logging (the ROS log file is complete), but never destroyed.
    Then what a normal interpreter exit does and needs no DDS: ``threading``'s shutdown (its exit
    hooks, then the non-daemon threads joined), the ``atexit`` handlers (Python logging's flush;
    rclpy registers none), stdout and stderr flushed. No finalizer or C++ static destructor runs
    after that: ``os._exit``.
    """
    # Hidden ('_'), one per process, and deaf to the command line's remapping: `__node:=actor_0`
    # would otherwise give it the stopped node's name, left in the graph until the lease ends.
    # Held until os._exit: a Node no longer referenced is destroyed, and the participant with it.
    if context.ok():
        _holds_participant = Node(f"_sdhn_exiting_{os.getpid()}", context=context,
                                  use_global_arguments=False, start_parameter_services=False,
                                  enable_rosout=False)
        for each in nodes:
            each.destroy_node()
        rclpy.try_shutdown(context=context)
    # else: shut down already (context.shutdown() stopped the node): no node can be created to
    # hold the participant, so the nodes are left as they are, to the lease like the participant.
    # The interpreter's own first step at exit: threading's exit hooks (a ThreadPoolExecutor's
    # workers told to end), then every non-daemon thread joined; the watchdog bounds it.
    threading._shutdown()  # type: ignore[attr-defined]
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # closed or broken: nothing left to say there
            stream.flush()
    os._exit(code)
