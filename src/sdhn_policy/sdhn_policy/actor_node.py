"""Per-robot actor node ``sdhn_policy actor``: one OS process per robot, NumPy policy only.

Launched as ``actor --ros-args -r __ns:=/sdhn/robot_<i> -p team_ns:=/sdhn -p robot_id:=<i>
-p num_robots:=<N>``. Subscribes to its own ``robot_<i>/obs`` and to the team's ``policy/weights``
(latched), publishes ``robot_<i>/action``, all under ``team_ns`` (names from
:mod:`sdhn_sim.ros.topics`; absolute, because the weights topic is the team's, not the robot's).
Nothing else: an actor never sees another robot's observation or the global state. The obs
subscription and the action publisher are created only once the actor holds weights (from
``weights_file`` at start, or the first valid weights message), so the simulator, which waits for
both before step 0, never starts a step this actor cannot answer. The decision logic lives in
:mod:`sdhn_policy.actor_core`; this file never imports torch.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence

from rclpy.context import Context
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription

from sdhn_msgs.msg import PolicyWeights, RobotAction, RobotObservation
from sdhn_policy.actor_core import ActorCore, Decision, Drop, runtime_class, runtime_from_file
from sdhn_policy.weights import WeightsError
from sdhn_sim.drops import DropKind
from sdhn_sim.ros import cdr, topics
from sdhn_sim.ros.params import boolean, declare, integer, string
from sdhn_sim.ros.qos import LATCHED, STEP
from sdhn_sim.ros.runner import ConfigError, run_node

PARAMETERS = {
    "team_ns": (topics.DEFAULT_TEAM_NS, string(f"team namespace; {topics.TEAM_NS_RULE}")),
    "robot_id": (0, integer("this robot's id, 0 <= robot_id < num_robots", 0)),
    "num_robots": (10, integer("team size N", 1)),
    "weights_file": ("", string("actor .safetensors file (with its .json sidecar), or an "
                                "exported actor.onnx (backend onnx); '' = wait for the weights "
                                "topic")),
    "greedy": (False, boolean("argmax actions instead of sampling")),
    "seed": (0, integer("seed of the action sampler", 0)),
    "backend": ("numpy", string("policy runtime: 'numpy' or 'onnx' (onnxruntime); same actions")),
}
FAIL_AFTER = 3  # wrong-length observations before any answer that end the actor
WEIGHTS_ALLOWED = ("allowed: an actor .safetensors file with its .json sidecar, or '' (wait for "
                   "the weights topic)")


class ActorNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("actor", context=context)
        p = declare(self, PARAMETERS)
        robot_id, num_robots, weights_file = p["robot_id"], p["num_robots"], p["weights_file"]
        self.ns = topics.check_team_ns(p["team_ns"])
        if robot_id >= num_robots:
            raise ConfigError(f"robot_id: got {robot_id}; allowed: 0 <= robot_id < num_robots "
                              f"({num_robots})")
        try:
            runtime_cls = runtime_class(p["backend"])
        except ValueError as e:
            raise ConfigError(str(e)) from None
        try:
            runtime = runtime_from_file(p["backend"], weights_file) if weights_file else None
            self.core = ActorCore(robot_id, num_robots, p["greedy"], p["seed"], runtime,
                                  runtime_cls=runtime_cls)
        except WeightsError as e:
            raise ConfigError(f"weights_file: {weights_file}: {e.reason}; {WEIGHTS_ALLOWED}") from e
        self.robot_id = robot_id
        self._action = RobotAction(robot_id=robot_id)
        self.drops: Counter[str] = Counter()
        self.failed_reason = ""  # set when this actor can never act (sdhn_sim.ros.runner)
        self.answered = False  # any observation answered yet
        self.unfit = 0  # observations of the wrong length before the first answer
        self.obs_sub: Subscription | None = None
        self.action_pub: Publisher | None = None
        weights_topic = topics.absolute(self.ns, topics.WEIGHTS)
        self.weights_sub = self.create_subscription(
            PolicyWeights, weights_topic, self.on_weights, LATCHED)
        if runtime is not None:
            self.open_step_topics()
        source = weights_file or f"waiting for {weights_topic}"
        self.get_logger().info(f"ready: robot {robot_id} of {num_robots}, greedy={p['greedy']}, "
                               f"backend={p['backend']}, "
                               f"weights: {source} (version {self.core.version})")

    def open_step_topics(self) -> None:
        """Create the obs subscription and the action publisher (once we can answer)."""
        self.action_pub = self.create_publisher(
            RobotAction, topics.absolute(self.ns, topics.robot_action(self.robot_id)), STEP)
        self.obs_sub = self.create_subscription(
            RobotObservation, topics.absolute(self.ns, topics.robot_obs(self.robot_id)),
            self.on_obs, STEP, raw=True)

    def on_weights(self, msg: PolicyWeights) -> None:
        try:
            new = self.core.offer_weights(msg.format, int(msg.version), bytes(msg.payload),
                                          msg.sha256)
        except WeightsError as e:
            self.drop(e.kind, f"weights version {msg.version}: {e.reason}; "
                      f"keeping version {self.core.version}")
            return
        if not new:
            return
        self.get_logger().info(f"weights version {msg.version} accepted (used from the next step)")
        if self.obs_sub is None:
            self.open_step_topics()

    def on_obs(self, data: bytes) -> None:
        # Raw CDR read at its offsets (sdhn_sim.ros.cdr): no Python message per step.
        try:
            msg = cdr.read_observation(data)
        except cdr.CdrError as e:
            self.drop(DropKind.UNDECODABLE, f"observation: {e}")
            return
        out = self.core.on_obs(msg.episode, msg.step, msg.robot_id, msg.num_robots, msg.obs,
                               done=msg.terminated or msg.truncated)
        if isinstance(out, Decision):
            self.answered = True
            assert self.action_pub is not None
            # One message, refilled per step (rclpy serialises at publish): no per-step message,
            # Header and Time objects. The stamp is the wall clock the node's ROS clock reads
            # (no simulated time in this graph), without building rclpy Time objects.
            a = self._action
            a.header.stamp.sec, a.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
            a.episode, a.step = msg.episode, msg.step
            a.action, a.log_prob, a.policy_version = out.action, out.log_prob, out.version
            self.action_pub.publish(a)
        elif isinstance(out, Drop):
            self.drop(out.kind, f"episode {msg.episode} step {msg.step}: {out.reason}")
            # Weights that do not fit the environment: the simulator re-sends step 0, every
            # copy the wrong length. One stray message after acting is only dropped (hostile
            # input must not end an actor); FAIL_AFTER of them before any answer end it (exit 1).
            if out.kind == DropKind.WRONG_OBS_LENGTH and not self.answered:
                self.unfit += 1
                if self.unfit >= FAIL_AFTER:
                    self.failed_reason = (f"robot {self.robot_id} cannot act: {out.reason}, "
                                          f"{self.unfit} times before any answer (weights do "
                                          "not fit the environment)")

    def drop(self, kind: str, detail: str) -> None:
        self.drops[kind] += 1
        if self.drops[kind] == 1:
            self.get_logger().warning(f"dropped ({kind}): {detail} (logged once per kind)")


def _on_stop(node: Node) -> None:
    if isinstance(node, ActorNode) and node.drops:
        node.get_logger().info(f"drops: {dict(node.drops)}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: ActorNode(context), argv, _on_stop)
