"""Drive managed (lifecycle) nodes through the standard ``lifecycle_msgs`` services.

What ``ros2 lifecycle set`` and nav2's lifecycle manager do, for the pip install (no ros2cli
wheels): a ``ChangeState`` request to ``<node>/change_state``, a ``GetState`` to
``<node>/get_state``. Non-blocking for the launcher's loop (:meth:`LifecycleClient.request`
returns a future, :meth:`LifecycleClient.spin` delivers replies), blocking for one-off use
(:func:`change_state`, :func:`get_state`).

    client = LifecycleClient()
    future = client.request("/sdhn/robot_0/actor", "configure")
    while not future.done(): client.spin(0.05)
    ok = future.result().success
    client.close()
"""

from __future__ import annotations

import time

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.client import Client
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.task import Future

# The transitions a user asks for, by the labels ``ros2 lifecycle set`` takes.
TRANSITIONS = {
    "configure": Transition.TRANSITION_CONFIGURE,
    "cleanup": Transition.TRANSITION_CLEANUP,
    "activate": Transition.TRANSITION_ACTIVATE,
    "deactivate": Transition.TRANSITION_DEACTIVATE,
    "shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,  # resolved by label (any state)
}


class LifecycleClient:
    """One rclpy node holding ChangeState/GetState clients for any number of managed nodes."""

    def __init__(self, name: str = "lifecycle_client") -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._change: dict[str, Client] = {}
        self._get: dict[str, Client] = {}

    def _clients(self, node: str) -> tuple[Client, Client]:
        if node not in self._change:
            self._change[node] = self.node.create_client(ChangeState, f"{node}/change_state")
            self._get[node] = self.node.create_client(GetState, f"{node}/get_state")
        return self._change[node], self._get[node]

    def ready(self, node: str) -> bool:
        """Whether ``node``'s lifecycle services are discovered (a request would be served)."""
        change, get = self._clients(node)
        return change.service_is_ready() and get.service_is_ready()

    def request(self, node: str, transition: str) -> Future:
        """Ask ``node`` for ``transition`` (a :data:`TRANSITIONS` label); the future's result is
        a ``ChangeState.Response`` (``success``)."""
        if transition not in TRANSITIONS:
            raise ValueError(f"transition: {transition!r}; allowed: {', '.join(TRANSITIONS)}")
        req = ChangeState.Request()
        # By label: the server resolves it from the current state (shutdown has three ids).
        req.transition.label = transition
        req.transition.id = TRANSITIONS[transition]
        return self._clients(node)[0].call_async(req)

    def request_state(self, node: str) -> Future:
        """The future's result is a ``GetState.Response`` (``current_state.label``)."""
        return self._clients(node)[1].call_async(GetState.Request())

    def spin(self, timeout_s: float) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def wait(self, future: Future, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < end:
            self.spin(0.05)
        return future.done()

    def wait_ready(self, node: str, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while not self.ready(node) and time.monotonic() < end:
            self.spin(0.05)
        return self.ready(node)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# The state a transition ends in when it succeeds (the lifecycle's primary states).
TARGET_STATES = {"configure": "inactive", "cleanup": "unconfigured", "activate": "active",
                 "deactivate": "inactive", "shutdown": "finalized"}
# How long one request waits for its answer before the outcome is checked and, if it was lost,
# the request is sent again. A server that discovers the client's request writer before its
# response reader serves the request but drops the answer (rmw: "failed to send response
# (timeout): client will not receive response"), so one unanswered request proves nothing.
ANSWER_S = 3.0


def change_state(client: LifecycleClient, node: str, transition: str,
                 timeout_s: float = 10.0) -> bool | None:
    """True/False as the node answered; None when it did not answer within ``timeout_s``.

    An answer lost in discovery is recovered: the node's state tells whether the transition
    took place (True), and a request that did not is sent again; a transition that fails
    fails again and is answered once the response path is matched (False)."""
    end = time.monotonic() + timeout_s
    if not client.wait_ready(node, timeout_s):
        return None
    while True:
        future = client.request(node, transition)
        if client.wait(future, min(ANSWER_S, max(0.0, end - time.monotonic()))):
            return bool(future.result().success)
        state = get_state(client, node, max(0.0, end - time.monotonic()))
        if state == TARGET_STATES[transition]:
            return True
        if state is None or time.monotonic() >= end:
            return None


def get_state(client: LifecycleClient, node: str, timeout_s: float = 10.0) -> str | None:
    """The node's state label ('unconfigured', 'inactive', 'active', 'finalized'), or None.
    Asked again every ``ANSWER_S`` while unanswered (a GetState changes nothing)."""
    end = time.monotonic() + timeout_s
    if not client.wait_ready(node, timeout_s):
        return None
    while time.monotonic() < end:
        future = client.request_state(node)
        if client.wait(future, min(ANSWER_S, end - time.monotonic())):
            return str(future.result().current_state.label)
    return None
