"""Per-robot actor node ``sdhn_policy actor``: one OS process per robot, NumPy policy only.

Launched as ``actor --ros-args -r __ns:=/sdhn/robot_<i> -p team_ns:=/sdhn -p robot_id:=<i>
-p num_robots:=<N>``. Subscribes to its own ``robot_<i>/obs`` and to the team's ``policy/weights``
(latched), publishes ``robot_<i>/action``, all under ``team_ns`` (names from
:mod:`sdhn_base.ros.topics`; absolute, because the weights topic is the team's, not the robot's).
Nothing else: an actor never sees another robot's observation or the global state. The decision
logic lives in :mod:`sdhn_policy.actor_core`; this file never imports torch.

A lifecycle node; with ``managed:=true`` driven through the standard ``lifecycle_msgs`` services
(``<robot ns>/actor/change_state``, ``get_state``; docs/lifecycle-and-diagnostics.md):
configure = load and validate ``weights_file`` (bad weights: the transition fails, the node stays
unconfigured and alive) and subscribe to the weights topic; activate = open the step topics and
act; deactivate = close them (the simulator counts this robot's steps as missed); cleanup = drop
the weights; shutdown = stop the process (exit 0). With ``managed:=false`` (the default) it
configures and activates itself at start, as a plain node would, offers no lifecycle services,
and bad weights end it with exit 2. The obs subscription and the action publisher exist only while
the node is active *and* holds weights, so the simulator, which waits for both before step 0,
never starts a step this actor cannot answer.

The obs subscription also waits for the action publisher's own side of matching: it is created
only once ``get_subscription_count()`` (the writer's matched readers) reaches ``action_readers``,
the nodes that read this robot's actions (1, the simulator; the launcher adds the recorder node
and the trainer). DDS matches each side on its own: a reader can count this writer before the
writer has matched it, and until then the writer sends that reader nothing. The simulator starts
step 0 only when every obs topic has all its subscribers, so holding this one back means every
reader of the actions has this robot's from step 0 (else, at several hundred steps a second, a
robot's first 1-8 actions were lost to the recording and the trainer). The wait is bounded by
``action_readers_timeout``: then a warning names the readers this process knows of and the obs
subscription is created anyway, so an actor restarted while a reader is gone for good (a dead
recorder) still comes back. A restarted actor waits as at start-up: the readers are there, and
its writer matches them within a discovery round.

Beside ours, two standard streams: ``robot_<i>/target_pose`` (``geometry_msgs/PoseStamped``, the
cell the chosen action moves to, frame ``map``; needs ``env`` to read the cell from the
observation; published only while someone subscribes) and ``/diagnostics`` (decision latency
p50/p99, weights version, drops per cause, 1 Hz).
"""

from __future__ import annotations

import signal
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from rclpy.context import Context
from rclpy.lifecycle import (
    LifecycleNode,
    LifecycleNodeMixin,
    LifecycleState,
    TransitionCallbackReturn,
)
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from sdhn_base.diagnostics import (
    OK,
    WARN,
    Report,
    RollingPercentiles,
    WindowCounts,
    drop_values,
    make_report,
)
from sdhn_base.drops import DropKind
from sdhn_base.ros import cdr, topics
from sdhn_base.ros.diagnostics import DiagnosticsPublisher
from sdhn_base.ros.params import boolean, declare, floating, integer, string
from sdhn_base.ros.qos import LATCHED, POSES, STEP, STEP_NEWEST
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_msgs.msg import PolicyWeights, RobotAction, RobotObservation
from sdhn_policy.actor_core import ActorCore, Decision, Drop, runtime_class, runtime_from_file
from sdhn_policy.dead_reckoning import Reckoner
from sdhn_policy.final_approach import FinalApproach
from sdhn_policy.stall_breaker import StallRule
from sdhn_policy.weights import WeightsError
from sdhn_sim.envs.registry import env_names
from sdhn_sim.poses import FRAME_ID, target_reader, yaw_quaternion

PARAMETERS = {
    "team_ns": (topics.DEFAULT_TEAM_NS, string(f"team namespace; {topics.TEAM_NS_RULE}")),
    "robot_id": (0, integer("this robot's id, 0 <= robot_id < num_robots", 0)),
    "num_robots": (10, integer("team size N", 1)),
    "weights_file": ("", string("actor .safetensors file (with its .json sidecar), or an "
                                "exported actor.onnx (backend onnx); '' = wait for the weights "
                                "topic")),
    "greedy": (False, boolean("argmax actions instead of sampling")),
    "temperature": (1.0, floating("sampling temperature (greedy false): actions drawn from "
                                  "softmax(logits / T); T < 1 leans towards the argmax but still "
                                  "leaves a standstill; 1 = the policy itself", 0.01, 100.0)),
    "break_stalls": (False, boolean("greedy true, MAIF: stall breaking, a robot whose play has "
                                    "stalled samples a few actions (sdhn_policy.stall_breaker)")),
    "stall_rule": (StallRule().text(), string("break_stalls: CALM,PROGRESS,SAMPLE[,T], the "
                                              "rule's step counts and sampling temperature")),
    "final_approach": (False, boolean("break_stalls true, needs env naming a MAIF grid: a robot "
                                      "whose free goal is in its window steps along a shortest "
                                      "free path to it, one on its goal stays unless stall "
                                      "breaking samples "
                                      "(sdhn_policy.final_approach)")),
    "seed": (0, integer("seed of the action sampler", 0)),
    "backend": ("numpy", string("policy runtime: 'numpy' or 'onnx' (onnxruntime); same actions")),
    "managed": (False, boolean("wait for lifecycle transitions (configure, activate) through the "
                               "lifecycle_msgs services; false = configure and activate at start")),
    "env": ("", string("environment name, to read this robot's cell from its observation for "
                       "target_pose; '' = no target_pose")),
    "realtime": (False, boolean("the simulator runs clock realtime: act on the newest "
                                "observation (queue depth 1) and take a later step than the next "
                                "one, the skipped steps counted")),
    "dead_reckoning": (False, boolean("MAIF or RWARE, needs env: move an observation that "
                                      "lags behind "
                                      "this robot's actions (RobotObservation.obs_age) forward "
                                      "by the actions it sent since (sdhn_policy.dead_reckoning);"
                                      " changes nothing on a current one")),
    "action_readers": (1, integer("nodes that subscribe to this robot's actions (1 = the "
                                  "simulator; the launcher adds the recorder node and the "
                                  "trainer): the obs subscription is created only once the action "
                                  "publisher has matched this many, so none of them misses the "
                                  "first actions; 0 = no wait", 0, 1000)),
    "action_readers_timeout": (30.0, floating("seconds to wait for action_readers; then a "
                                              "warning names what is missing and the obs "
                                              "subscription is created anyway", 0.0, 3600.0)),
}
FAIL_AFTER = 3  # wrong-length observations before any answer that end the actor
WEIGHTS_ALLOWED = ("allowed: an actor .safetensors file with its .json sidecar, or '' (wait for "
                   "the weights topic)")


SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
SHUTDOWN_GRACE_S = 0.2  # after the shutdown transition, time for its service reply to go out
# While the obs subscription waits for the action readers: at most this much later than the
# match, against discovery's seconds; not faster, as an actor host polls for each of its robots.
READERS_POLL_S = 0.05


class ActorNode(LifecycleNode):
    def __init__(self, context: Context, namespace: str | None = None) -> None:
        # LifecycleNode's own __init__ in two halves: the lifecycle interface (services, the
        # transition_event topic) only once the parameters, and without ``managed`` the weights,
        # are known good, so a configuration error leaves no topic behind (exit 2, one line).
        # ``namespace``: the robot's, when several actors share a process (sdhn_policy.actor_host);
        # None = the process's own (``-r __ns:=``).
        Node.__init__(self, "actor", context=context, namespace=namespace)
        p = declare(self, PARAMETERS)
        robot_id, num_robots = p["robot_id"], p["num_robots"]
        self.ns = topics.check_team_ns(p["team_ns"])
        if robot_id >= num_robots:
            raise ConfigError(f"robot_id: got {robot_id}; allowed: 0 <= robot_id < num_robots "
                              f"({num_robots})")
        self.stall_rule: StallRule | None = None
        if p["break_stalls"]:
            if not p["greedy"]:
                raise ConfigError("break_stalls: applies only to greedy: true (sampled play "
                                  "has no standstill to break)")
            try:
                self.stall_rule = StallRule.parse(p["stall_rule"])
            except ValueError as e:
                raise ConfigError(f"stall_rule: {e}") from None
        self.approach: FinalApproach | None = None
        if p["final_approach"]:
            if self.stall_rule is None:
                raise ConfigError("final_approach: applies only with break_stalls: true (its "
                                  "hold would deadlock corridors without stall breaking)")
            try:
                self.approach = FinalApproach.for_env(p["env"])
            except ValueError as e:
                raise ConfigError(f"final_approach: needs env to name the grid; {e}") from None
        self.target = target_reader(p["env"]) if p["env"] else None
        if p["env"] and self.target is None:
            raise ConfigError(f"env: unknown {p['env']!r}; allowed: '' or one of "
                              f"{', '.join(env_names())}")
        # Dead reckoning: the env's rule, built once here (an RWARE rule builds the warehouse to
        # read its layout) and handed to each core this node loads; one core at a time.
        self.reckoner: Reckoner | None = None
        if p["dead_reckoning"]:
            from sdhn_policy.dead_reckoning import reckoner_for
            try:
                self.reckoner = reckoner_for(p["env"])
            except ValueError as e:
                raise ConfigError(f"dead_reckoning: needs env to name the grid or warehouse; "
                                  f"{e}") from None
        self.params: dict[str, Any] = p
        try:
            self.runtime_cls = runtime_class(p["backend"])
        except ValueError as e:
            raise ConfigError(str(e)) from None
        self.robot_id = robot_id
        self.core: ActorCore | None = None  # set by configure
        self._loaded: ActorCore | None = None  # unmanaged: loaded here, taken by configure
        if not p["managed"]:
            try:
                self._loaded = self.load_core()
            except WeightsError as e:
                raise ConfigError(self.weights_error(e)) from e
        # Unmanaged, nothing drives it: no lifecycle services or transition_event topic (a dozen
        # DDS endpoints per actor that every participant of the graph would discover).
        LifecycleNodeMixin.__init__(self, enable_communication_interface=p["managed"])
        self.phase = "unconfigured"  # the lifecycle state, for logs and diagnostics
        self.configure_error = ""  # why the last configure failed
        self._action = cdr.ActionWriter(robot_id)  # the action's CDR, rewritten per step
        self._target = PoseStamped()
        self._target.header.frame_id = FRAME_ID
        self.drops: Counter[str] = Counter()
        self.failed_reason = ""  # set when this actor can never act (sdhn_base.ros.runner)
        self.answered = False  # any observation answered yet
        self.unfit = 0  # observations of the wrong length before the first answer
        self.weights_sub: Subscription | None = None
        self.obs_sub: Subscription | None = None
        self.action_pub: Publisher | None = None
        self.target_pub: Publisher | None = None
        self._readers_timer: Timer | None = None  # exists only while the obs waits for readers
        self._readers_since = 0.0  # monotonic time the action publisher was created
        self.latency_ms = RollingPercentiles(1000)  # obs received -> action sent
        self._drops_window = WindowCounts()
        self.diagnostics = DiagnosticsPublisher(self, self.diagnostics_report)
        how = "managed: waiting for configure" if p["managed"] else "configuring itself"
        stalls = self.stall_rule.text() if self.stall_rule else "off"
        self.get_logger().info(f"ready: robot {robot_id} of {num_robots}, greedy={p['greedy']}, "
                               f"temperature={p['temperature']:g}, break_stalls={stalls}, "
                               f"final_approach={p['final_approach']}, "
                               f"dead_reckoning={p['dead_reckoning']}, backend={p['backend']}, "
                               f"{how}")

    # -- lifecycle transitions (lifecycle_msgs/srv/ChangeState, or autostart) -----------------

    def load_core(self) -> ActorCore:
        """The policy state machine with ``weights_file`` loaded (WeightsError if it is bad)."""
        p, weights_file = self.params, self.params["weights_file"]
        runtime = runtime_from_file(p["backend"], weights_file) if weights_file else None
        if self.reckoner is not None:
            # as newly built: a core loaded again after cleanup keeps nothing of the episode
            # the previous core reckoned
            self.reckoner.reset()
        return ActorCore(self.robot_id, p["num_robots"], p["greedy"], p["seed"], runtime,
                         runtime_cls=self.runtime_cls, temperature=p["temperature"],
                         stall_rule=self.stall_rule, approach=self.approach,
                         skip_ahead=p["realtime"],
                         reckoner=self.reckoner)

    def weights_error(self, e: WeightsError) -> str:
        return f"weights_file: {self.params['weights_file']}: {e.reason}; {WEIGHTS_ALLOWED}"

    def destroy_node(self) -> None:
        # rclpy's LifecycleNode leaves its state machine alive, and the state machine holds the
        # rcl node: the node was never finalised, so the DDS participant outlived rclpy and was
        # deleted by Fast DDS's static factory destructor at exit, where it can deadlock with a
        # departing peer's discovery callback (seen: actors hung past SIGINT + 10 s, SIGKILLed).
        super().destroy_node()
        self._state_machine.destroy_when_not_in_use()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        weights_file = self.params["weights_file"]
        try:
            self.core = self._loaded if self._loaded is not None else self.load_core()
            self._loaded = None
        except WeightsError as e:
            self.configure_error = self.weights_error(e)
            self.get_logger().error(f"configure failed: {self.configure_error}")
            return FAILURE
        weights_topic = topics.absolute(self.ns, topics.WEIGHTS)
        self.weights_sub = self.create_subscription(
            PolicyWeights, weights_topic, self.on_weights, LATCHED)
        self.phase, self.configure_error = "inactive", ""
        source = weights_file or f"waiting for {weights_topic}"
        self.get_logger().info(f"configured: weights {source} (version {self.core.version})")
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        assert self.core is not None
        self.core.forget_position()
        self.phase = "active"
        if self.core.runtime is not None:
            self.open_step_topics()
        self.get_logger().info(f"activated (weights version {self.core.version})")
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.close_step_topics()
        self.phase = "inactive"
        self.get_logger().info("deactivated: not acting (the simulator counts this robot's "
                               "steps as missed)")
        return SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.release()
        self.get_logger().info("cleaned up: weights dropped")
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.release()
        self.phase = "finalized"
        self.get_logger().info("shutdown: stopping")
        self.create_timer(SHUTDOWN_GRACE_S, self.stop_process)
        return SUCCESS

    def stop_process(self) -> None:
        """run_node's own stop path (its SIGTERM flag), once the reply to the shutdown transition
        has gone out: on_stop runs, the node is destroyed, exit code 0."""
        signal.raise_signal(signal.SIGTERM)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.release()
        self.get_logger().error(f"error in a transition from {state.label}: back to unconfigured")
        return SUCCESS

    def release(self) -> None:
        """Back to unconfigured: no step topics, no weights subscription, no weights."""
        self.close_step_topics()
        if self.weights_sub is not None:
            self.destroy_subscription(self.weights_sub)
            self.weights_sub = None
        self.core = None
        self.phase = "unconfigured"

    def open_step_topics(self) -> None:
        """Create the action publisher (active, and able to answer), then the obs subscription
        once the publisher has matched every action reader (module docstring)."""
        self.action_pub = self.create_publisher(
            RobotAction, topics.absolute(self.ns, topics.robot_action(self.robot_id)), STEP)
        if self.target is not None:
            self.target_pub = self.create_publisher(
                PoseStamped, topics.absolute(self.ns, topics.robot_target_pose(self.robot_id)),
                POSES)
        self._readers_since = time.monotonic()
        if not self.open_obs_when_read():
            self._readers_timer = self.create_timer(READERS_POLL_S, self.open_obs_when_read)

    def open_obs_when_read(self) -> bool:
        """Create the obs subscription if the action publisher has matched ``action_readers``
        readers, or ``action_readers_timeout`` has passed (a warning); whether it is done."""
        pub = self.action_pub
        if pub is None:  # closed while waiting
            self._stop_readers_timer()
            return True
        want, timeout = self.params["action_readers"], self.params["action_readers_timeout"]
        matched, waited = pub.get_subscription_count(), time.monotonic() - self._readers_since
        if matched < want and waited < timeout:
            return False
        self._stop_readers_timer()
        if matched >= want:
            self.get_logger().info(f"action writer matched {matched} of {want} action readers "
                                   f"after {waited:.2f}s; subscribing to observations")
        else:
            known = sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                           for i in self.get_subscriptions_info_by_topic(pub.topic_name))
            self.get_logger().warning(
                f"action writer matched {matched} of {want} action readers in {waited:.1f}s "
                f"(action_readers_timeout); subscribers of {pub.topic_name} this process knows "
                f"of: {', '.join(known) or 'none'}; subscribing to observations anyway: a reader "
                "not matched yet misses this robot's actions until it is")
        self.obs_sub = self.create_subscription(
            RobotObservation, topics.absolute(self.ns, topics.robot_obs(self.robot_id)),
            self.on_obs, STEP_NEWEST if self.params["realtime"] else STEP, raw=True)
        return True

    def _stop_readers_timer(self) -> None:
        if self._readers_timer is not None:
            self.destroy_timer(self._readers_timer)
            self._readers_timer = None

    def close_step_topics(self) -> None:
        self._stop_readers_timer()
        if self.obs_sub is not None:
            self.destroy_subscription(self.obs_sub)
        for pub in (self.action_pub, self.target_pub):
            if pub is not None:
                self.destroy_publisher(pub)
        self.obs_sub = self.action_pub = self.target_pub = None

    # -- callbacks -----------------------------------------------------------------------------

    def on_weights(self, msg: PolicyWeights) -> None:
        if self.core is None:
            return
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
        if self.action_pub is None and self.phase == "active":
            self.open_step_topics()

    def on_obs(self, data: bytes) -> None:
        t0 = time.perf_counter()
        if self.core is None or self.action_pub is None:
            # Not active: an observation the executor had queued before deactivate closed the
            # subscription still arrives here once; the simulator counts the step as missed.
            return
        # Raw CDR read at its offsets (sdhn_base.ros.cdr): no Python message per step.
        try:
            msg = cdr.read_observation(data)
        except cdr.CdrError as e:
            self.drop(DropKind.UNDECODABLE, f"observation: {e}")
            return
        out = self.core.on_obs(msg.episode, msg.step, msg.robot_id, msg.num_robots, msg.obs,
                               done=msg.terminated or msg.truncated, obs_age=msg.obs_age)
        if isinstance(out, Decision):
            self.answered = True
            # The action written straight as CDR and published as bytes (sdhn_base.ros.cdr): no
            # message filled through its checked setters, no conversion to C. The stamp is the
            # wall clock the node's ROS clock reads (no simulated time in this graph), without
            # building rclpy Time objects.
            now = time.time_ns()
            self.action_pub.publish(self._action.write(
                now, msg.episode, msg.step, action=out.action, log_prob=out.log_prob,
                policy_version=out.version))
            self.latency_ms.add((time.perf_counter() - t0) * 1e3)
            if self.target_pub is not None and self.target_pub.get_subscription_count():
                sec, nanosec = divmod(now, 1_000_000_000)
                self.publish_target(msg.obs, out.action, Time(sec=sec, nanosec=nanosec))
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

    def publish_target(self, obs: Any, action: int, stamp: Any) -> None:
        """The cell ``action`` moves to, as a map-frame pose facing the move (after the action,
        off the decision's latency)."""
        assert self.target is not None and self.target_pub is not None
        x, y, yaw = self.target(obs, action)
        t = self._target
        t.header.stamp = stamp
        t.pose.position.x, t.pose.position.y = x, y
        t.pose.orientation.z, t.pose.orientation.w = yaw_quaternion(yaw)
        self.target_pub.publish(t)

    def diagnostics_report(self) -> Report:
        lat = self.latency_ms
        values: dict[str, float | int | str] = {
            "lifecycle_state": self.phase,
            "weights_version": self.core.version if self.core is not None else 0,
            "decisions": lat.count,
            "decision_latency_p50_ms": lat.percentile(50),
            "decision_latency_p99_ms": lat.percentile(99),
        }
        if self.params["realtime"]:
            values["skipped_steps"] = self.core.skipped if self.core is not None else 0
        if self.reckoner is not None:  # observations moved forward by this robot's unseen actions
            values["dead_reckoned"] = self.core.reckoned if self.core is not None else 0
        values |= drop_values(self.drops, self._drops_window.new(self.drops))
        waiting = self.phase == "active" and self.obs_sub is None  # a WARN while active
        if self.phase != "active":
            note = f"{self.phase}: not acting" + (f" ({self.configure_error})"
                                                  if self.configure_error else "")
        elif self.action_pub is None:  # the step topics open once weights are held
            note = "active, waiting for weights"
        elif self.obs_sub is None:  # the obs subscription waits for the action readers
            note = "active, waiting for its action readers"
        else:
            note = ""
        return make_report(self.get_fully_qualified_name(), self.ns, values,
                           ("decision_latency_p99_ms", "dropped_in_window"), note,
                           floor=WARN if waiting else OK)

    def drop(self, kind: str, detail: str) -> None:
        self.drops[kind] += 1
        if self.drops[kind] == 1:
            self.get_logger().warning(f"dropped ({kind}): {detail} (logged once per kind)")


def _on_stop(node: Node) -> None:
    if isinstance(node, ActorNode) and node.drops:
        node.get_logger().info(f"drops: {dict(node.drops)}")


def make_actor(context: Context, _args: list[str], namespace: str | None = None) -> ActorNode:
    """The node; unless ``managed``, configured and activated at once (bad weights: ConfigError
    while it is built, exit 2)."""
    node = ActorNode(context, namespace)
    # unmanaged: the weights were checked when the node was built
    if not node.params["managed"] and (node.trigger_configure() != SUCCESS
                                       or node.trigger_activate() != SUCCESS):
        raise ConfigError(node.configure_error or "weights_file: configure failed")
    return node


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(make_actor, argv, _on_stop)
