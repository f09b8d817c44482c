"""Trainer node: the centralised learner of the ROS deployment (``sdhn_train trainer``).

Subscribes to every robot's obs and action and to ``state`` (N from the env), assembles team
transitions by (episode, step) (``sdhn_train.transitions``) on the executor thread, and hands
every ``rollout_steps`` transitions to the learner offload *process*
(``sdhn_train.learner_offload``:
raw NumPy frames over a pipe, nothing pickled), which runs the algorithm's learner, the same as
the in-process trainer's (``sdhn_train.stream_learner``), checkpoints (atomic) and sends the new
weights back. The node publishes them (version + 1, LATCHED, stamped with the update's end) and
the sampled hypergraphs (SENSOR, SDHN only). The callbacks only assemble: an update, however
long, cannot delay them. Version 1 (or the resumed version) is published at start.

Every dropped message, step or rollout is counted per cause and logged once per cause; the counts,
the transitions assembled and learned, and the executor's longest stall go to
``<status dir>/trainer.status.json`` (``sdhn_base.ros.status``) for the launcher's status line,
and once a second to ``/diagnostics`` (queue depth, drops per cause, weights version;
``sdhn_base.diagnostics``).

Parameters (typed, with descriptors): env and algo (a name of the env / algorithm registry), seed
(>= 0), run_dir ("" = runs/<env>__<algo>__<seed>__ros-<time>), rollout_steps (>= 2), config
("" = defaults; YAML of the in-process trainer config), resume, team_ns, init_from (an exported
actor to start from, the in-process ``actor.init_from``) and total_steps (transitions to learn
from, as the in-process ``train.total_steps``; 0 = until stopped: once the learner has learned
that many, later rollouts are counted, not learned; the simulator goes on until stopped). The YAML's
env/algo/seed/rollout length are replaced by the parameters; the ROS stream is one environment,
so env.num_envs and ppo.num_minibatches are 1. Checking them, merging the config and resuming are
plain functions and methods below (``configure``, ``start``); the constructor declares.
"""

from __future__ import annotations

import array
import collections
import functools
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.context import Context
from rclpy.node import Node
from rclpy.subscription import Subscription
from rclpy.time import Time

from sdhn_base.diagnostics import Report, WindowCounts, drop_values, make_report
from sdhn_base.drops import DropKind, describe
from sdhn_base.ros import cdr, params, topics
from sdhn_base.ros.diagnostics import DiagnosticsPublisher
from sdhn_base.ros.qos import LATCHED, SENSOR, STEP, STEP_DEPTH
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_base.ros.status import write_status
from sdhn_msgs.msg import (
    EpisodeSummary,
    Hypergraph,
    PolicyWeights,
    RobotAction,
    RobotObservation,
    TeamState,
)
from sdhn_sim.envs.registry import env_names, make_env
from sdhn_sim.episode import EpisodeResult
from sdhn_train import checkpoint as ckpt
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.config import Config, apply_dict, load_yaml, validate
from sdhn_train.config import ConfigError as TrainConfigError
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learner_offload import (
    HypergraphSample,
    LearnerClient,
    LearnerStartError,
    LearnerUpdate,
    WeightsBlob,
)
from sdhn_train.transitions import TransitionAssembler

QUEUE_ROLLOUTS = 4  # rollouts waiting for the pipe (the learner's receiver drains it at once)
STATUS_PERIOD_S = 2.0
LAG_PERIOD_S = 0.1
# Out of step: this many incomplete steps in a row (two full settle windows) with no transition
# between them. Seen once after a restart under load (a restarted trainer joining a loop at ~500
# steps/s): every step lacked something, for minutes, and nothing was learned. Fresh readers
# (new DDS endpoints, matched anew) are the recovery; at most once per RESUBSCRIBE_EVERY_S.
OUT_OF_STEP_STEPS = 2 * STEP_DEPTH
RESUBSCRIBE_EVERY_S = 10.0


@dataclass(frozen=True)
class TrainerParams:
    """The node's parameters once declared (names, defaults and descriptors: PARAMETERS)."""

    env: str
    algo: str
    seed: int
    run_dir: str
    rollout_steps: int
    config: str
    resume: bool
    team_ns: str
    init_from: str
    total_steps: int


# Read-only: the learner's run is fixed once started (a change would need a new run_dir).
PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    "env": ("maif-10", params.string("environment", read_only=True,
                                     constraints=f"one of {', '.join(env_names())}")),
    "algo": ("sdhn", params.string("algorithm", read_only=True,
                                   constraints=f"one of {', '.join(ALGO_NAMES)}")),
    "seed": (1, params.integer("seed of everything", 0, read_only=True,
                               constraints="an integer >= 0")),
    "run_dir": ("", params.string("run directory; '' = runs/<env>__<algo>__<seed>__ros-<time>",
                                  read_only=True, constraints="a path")),
    "rollout_steps": (128, params.integer("team steps per update", 2, read_only=True,
                                          constraints="an integer >= 2")),
    "config": ("", params.string("YAML of the in-process trainer config; '' = defaults",
                                 read_only=True, constraints="a YAML file or ''")),
    "resume": (False, params.boolean("continue from the newest checkpoint in run_dir",
                                     read_only=True)),
    "team_ns": ("/sdhn", params.string("namespace of the team's topics", read_only=True,
                                       constraints="an absolute namespace like /sdhn")),
    "init_from": ("", params.string(
        "exported actor (.safetensors) to start from, as actor.init_from of the in-process "
        "trainer; '' = fresh (a resume loads its checkpoint)", read_only=True,
        constraints="an actor .safetensors file or ''")),
    "total_steps": (0, params.integer("team steps to learn from; 0 = until stopped", 0,
                                      read_only=True, constraints="an integer >= 0")),
}


def default_params(**changes: Any) -> TrainerParams:
    """The parameters as a node started with no ``-p`` would have them, with ``changes``."""
    return TrainerParams(**{**{name: default for name, (default, _) in PARAMETERS.items()},
                            **changes})


def declare_parameters(node: Node) -> TrainerParams:
    """Declare every parameter with its descriptor (the helper every node uses); a value of the
    wrong type or out of range is a ConfigError naming the parameter and what is allowed."""
    return TrainerParams(**params.declare(node, PARAMETERS))


def check_params(p: TrainerParams) -> None:
    """The checks a descriptor cannot express: registry names and the namespace rule."""
    if p.env not in env_names():
        raise ConfigError(f"env: {p.env!r} is unknown; allowed: {', '.join(env_names())}")
    if p.algo not in ALGO_NAMES:
        raise ConfigError(f"algo: {p.algo!r} is unknown; allowed: {', '.join(ALGO_NAMES)}")
    topics.check_team_ns(p.team_ns)


def build_config(env: str, algo: str, seed: int, rollout_steps: int, config_path: str, *,
                 init_from: str = "") -> Config:
    """The in-process trainer's typed config with the node's parameters laid over it."""
    cfg = Config()
    if config_path:
        if not Path(config_path).is_file():
            raise ConfigError(f"config: no such file {config_path!r}; allowed: a YAML file or ''")
        try:
            apply_dict(cfg, load_yaml(config_path))
        except (TrainConfigError, ValueError) as e:
            raise ConfigError(f"config: {config_path}: {e}") from e
    cfg.env.name, cfg.algo.name, cfg.train.seed = env, algo, seed
    cfg.ppo.rollout_len = rollout_steps
    cfg.env.num_envs, cfg.ppo.num_minibatches = 1, 1
    if init_from:
        if not Path(init_from).is_file():
            raise ConfigError(f"init_from: no such file {init_from!r}; allowed: an actor "
                              ".safetensors file or ''")
        cfg.actor.init_from = init_from
    cfg.log.progress = False
    try:
        validate(cfg)
    except TrainConfigError as e:
        raise ConfigError(f"config: {e}") from e
    return cfg


def check_run_dir(p: TrainerParams) -> Path:
    """The node's run_dir; ConfigError when it holds an earlier run's checkpoints and resume is
    off (a fresh run would overwrite them)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(p.run_dir or f"runs/{p.env}__{p.algo}__{p.seed}__ros-{stamp}")
    if ckpt.latest_checkpoint(run_dir) is not None and not p.resume:
        raise ConfigError(f"run_dir: {run_dir} holds checkpoints of an earlier run; "
                          "allowed: resume:=true, or an empty or new run_dir")
    return run_dir


def start_learner(p: TrainerParams, cfg: Config, run_dir: Path) -> LearnerClient:
    """The learner offload process (``sdhn_train.learner_offload``), started and holding its first
    version (fresh: checkpointed, warm-started from ``init_from``; resume: loaded). ConfigError
    for a checkpoint or an ``init_from`` actor it cannot load."""
    try:
        return LearnerClient(cfg.to_dict(), run_dir, p.resume, total_steps=p.total_steps)
    except LearnerStartError as e:
        if e.config:
            raise ConfigError(str(e)) from e
        raise


class TrainerNode(Node):
    def __init__(self, context: Context) -> None:
        """Declares: parameters, the learner process, publishers, subscriptions, timers; then
        publishes the first weights and starts the learner's stream (``start``)."""
        super().__init__("trainer", context=context)
        p = declare_parameters(self)
        cfg = self.configure(p)
        # The learner runs in its own process: nothing it does can hold this node's executor.
        # Started before any topic exists: a checkpoint it cannot resume from is a config error.
        self.learner = start_learner(p, cfg, self.run_dir)
        self.version = self.learner.start_weights.version
        self.transitions_learned = self.learner.start_transitions
        self.weights_pub = self.create_publisher(
            PolicyWeights, topics.absolute(self.ns, topics.WEIGHTS), LATCHED)
        self.hypergraph_pub = self.create_publisher(
            Hypergraph, topics.absolute(self.ns, topics.HYPERGRAPH), SENSOR)
        self._subscribe_steps()
        self.create_subscription(EpisodeSummary, topics.absolute(self.ns, topics.EPISODE),
                                 self.on_episode, STEP)
        self.create_timer(LAG_PERIOD_S, self.on_lag_timer)
        self.diagnostics = DiagnosticsPublisher(self, self.diagnostics_report)
        self.start(cfg)

    def configure(self, p: TrainerParams) -> Config:
        """Check the parameters, build the learner's config and the assembler, and set the
        node's bookkeeping; ConfigError (one line) for anything invalid."""
        check_params(p)
        cfg = build_config(p.env, p.algo, p.seed, p.rollout_steps, p.config,
                           init_from=p.init_from)
        self.total_steps = p.total_steps
        self.run_dir = check_run_dir(p)
        env = make_env(cfg.env.name, num_envs=1, seed=cfg.train.seed)
        self.info = EnvInfo.of(env)  # raw sizes, as the messages carry them
        self.ns = p.team_ns
        n = self.info.num_robots
        self.assembler = TransitionAssembler(n, self.info.obs_size, self.info.state_size,
                                             self.info.num_actions,
                                             rollout_steps=cfg.ppo.rollout_len,
                                             max_steps=env.max_steps,
                                             # a message later than the queue depth is lost
                                             # anyway; steps the sim 'stay'ed drop at once
                                             settle_lag=STEP_DEPTH)
        self.dropped: dict[str, int] = {}  # message- and rollout-level drops seen by the node
        self.learner_dropped: dict[str, int] = {}  # reported by the learner offload process
        self._logged_causes: set[str] = set()
        self._episodes: list[dict[str, Any]] = []
        self._last_status = ""
        self._lag_max = 0.0  # longest executor delay of the lag timer since the last status
        self._lag_worst = 0.0
        self._lag_due: float | None = None  # the first tick only starts the clock
        # (version, update end, published) of the recent updates, for the status file
        self.updates: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=200)
        self._obs_topics = [topics.absolute(self.ns, topics.robot_obs(i)) for i in range(n)]
        self._action_topics = [topics.absolute(self.ns, topics.robot_action(i))
                               for i in range(n)]
        self._step_subs: list[Subscription] = []
        self.resubscribed = 0
        self._t_resubscribed = -float("inf")
        self._drops_window = WindowCounts()
        self._stop = threading.Event()
        return cfg

    def start(self, cfg: Config) -> None:
        """Publish the first (or resumed) weights, start the learner's stream and the status
        thread, and say so in one line."""
        self.publish_weights(self.learner.start_weights, time.time())
        self.learner.start(self.on_update, self.on_learner_error)
        self.status_thread = threading.Thread(target=self.status_loop, name="status", daemon=True)
        self.status_thread.start()
        how = f"resumed from {self.learner.resumed}" if self.learner.resumed else "fresh"
        self.get_logger().info(
            f"ready: env={cfg.env.name} algo={cfg.algo.name} robots={self.info.num_robots} "
            f"rollout_steps={cfg.ppo.rollout_len} version={self.version} ({how}) "
            f"init_from={cfg.actor.init_from or '-'} total_steps={self.total_steps or '-'} "
            f"run_dir={self.run_dir} learner_pid={self.learner.process.pid}")

    # -- callbacks (executor thread): validate, hand to the assembler, queue rollouts --------

    def _count(self, kind: str, detail: str, n: int = 1) -> None:
        self.dropped[kind] = self.dropped.get(kind, 0) + n
        self._log_once(kind, detail)

    def _log_once(self, kind: str, detail: str) -> None:
        if kind not in self._logged_causes:
            self._logged_causes.add(kind)
            self.get_logger().warning(
                f"dropped: {describe(kind)}: {detail}; counting, logged once per cause")

    def _drop(self, kind: str | None, topic: str, detail: str) -> None:
        if kind is not None:
            self._count(kind, f"on {topic}: {detail}")

    # The step topics arrive as raw CDR (``raw=True``) and are read by ``sdhn_base.ros.cdr``: no
    # Python message objects per message (41 a step at N = 20), which kept the node behind the
    # loop under load.

    def on_obs(self, robot: int, data: bytes) -> None:
        try:
            m = cdr.read_observation(data)
        except cdr.CdrError as e:
            self._drop(DropKind.UNDECODABLE, self._obs_topics[robot], str(e))
            return
        if m.robot_id != robot:
            self._drop(DropKind.WRONG_ROBOT, self._obs_topics[robot],
                       f"robot_id={m.robot_id}")
            return
        reason = self.assembler.add_obs(m.episode, m.step, m.robot_id, m.obs,
                                        num_robots=m.num_robots, terminated=m.terminated,
                                        truncated=m.truncated)
        if reason is not None:
            self._drop(reason, self._obs_topics[robot],
                       f"episode {m.episode} step {m.step} len {m.obs.size}")
        self._queue_ready()

    def on_action(self, robot: int, data: bytes) -> None:
        try:
            m = cdr.read_action(data)
        except cdr.CdrError as e:
            self._drop(DropKind.UNDECODABLE, self._action_topics[robot], str(e))
            return
        if m.robot_id != robot:
            self._drop(DropKind.WRONG_ROBOT, self._action_topics[robot],
                       f"robot_id={m.robot_id}")
            return
        reason = self.assembler.add_action(m.episode, m.step, m.robot_id, m.action,
                                           log_prob=m.log_prob, version=m.policy_version)
        if reason is not None:
            self._drop(reason, self._action_topics[robot], f"episode {m.episode} step "
                       f"{m.step} action {m.action} log_prob {m.log_prob}")
        self._queue_ready()

    def on_state(self, data: bytes) -> None:
        try:
            m = cdr.read_state(data)
        except cdr.CdrError as e:
            self._drop(DropKind.UNDECODABLE, topics.absolute(self.ns, topics.STATE), str(e))
            return
        reason = self.assembler.add_state(m.episode, m.step, m.state, num_robots=m.num_robots,
                                          team_reward=m.team_reward, terminated=m.terminated,
                                          truncated=m.truncated, missed=m.missed_actions)
        if reason is not None:
            self._drop(reason, topics.absolute(self.ns, topics.STATE),
                       f"episode {m.episode} step {m.step} len {m.state.size}")
        self._queue_ready()

    def on_episode(self, m: EpisodeSummary) -> None:
        self._episodes.append(EpisodeResult.from_message(m).to_event())

    def on_lag_timer(self) -> None:
        """How late the executor runs a 10 Hz timer: the longest stall of the callbacks, which
        (times the message rate) is the queue depth the observer subscriptions need."""
        now = time.monotonic()
        if self._lag_due is not None:
            self._lag_max = max(self._lag_max, now - self._lag_due)
        self._lag_due = now + LAG_PERIOD_S
        self.check_in_step(now)

    def _subscribe_steps(self) -> None:
        """(Re)create the subscriptions of the step topics (N obs, N actions, the state)."""
        for sub in self._step_subs:
            self.destroy_subscription(sub)
        n = self.assembler.n
        subs = []
        for i in range(n):
            subs.append(self.create_subscription(
                RobotObservation, self._obs_topics[i], functools.partial(self.on_obs, i), STEP,
                raw=True))
            subs.append(self.create_subscription(
                RobotAction, self._action_topics[i], functools.partial(self.on_action, i), STEP,
                raw=True))
        subs.append(self.create_subscription(
            TeamState, topics.absolute(self.ns, topics.STATE), self.on_state, STEP, raw=True))
        self._step_subs = subs

    def check_in_step(self, now: float) -> bool:
        """Re-create the step subscriptions if the trainer is out of step with the team (see
        OUT_OF_STEP_STEPS); returns whether it did. The warning names what the steps lacked."""
        st = self.assembler.stats
        if (st.incomplete_run < OUT_OF_STEP_STEPS
                or now - self._t_resubscribed < RESUBSCRIBE_EVERY_S):
            return False
        lacking = sorted(st.missing.items(), key=lambda kv: -kv[1])[:6]
        self.get_logger().warning(
            f"out of step: the last {st.incomplete_run} steps were all incomplete and none was "
            f"a transition (lacking so far: {dict(lacking)}); re-creating the step "
            "subscriptions")
        self._subscribe_steps()
        self.resubscribed += 1
        self._t_resubscribed = now
        st.incomplete_run = 0
        return True

    def _queue_ready(self) -> None:
        for kind, count in self.assembler.stats.dropped.items():
            if kind not in self._logged_causes:  # step-level drops found by the assembler
                self._log_once(kind, f"{count} so far")
        while (ready := self.assembler.pop_rollout()) is not None:
            if self.total_steps and self.transitions_learned >= self.total_steps:
                self._count(DropKind.PAST_TOTAL_STEPS, f"total_steps={self.total_steps} reached")
                continue
            if self.learner.waiting >= QUEUE_ROLLOUTS:
                self._count(DropKind.LEARNER_BUSY, f"{QUEUE_ROLLOUTS} rollouts waiting to be sent")
                continue
            episodes, self._episodes = self._episodes, []
            self.learner.submit(ready, episodes)  # queues only; a sender thread writes the pipe

    # -- status (own thread): a file for the launcher, a log line when it changes ------------

    def all_drops(self) -> dict[str, int]:
        """Every drop so far by cause: the node's, the assembler's and the learner's."""
        drops: dict[str, int] = {}
        for source in (dict(self.dropped), dict(self.assembler.stats.dropped),
                       dict(self.learner_dropped)):
            for kind, count in source.items():
                drops[kind] = drops.get(kind, 0) + count
        return drops

    def diagnostics_report(self) -> Report:
        drops = self.all_drops()
        st = self.assembler.stats
        values: dict[str, float | int | str] = {
            "weights_version": self.version, "queue_depth": self.learner.waiting,
            "pending_records": self.assembler.pending_records, "transitions": st.transitions,
            "transitions_learned": self.transitions_learned, "rollouts": st.rollouts,
        }
        values |= drop_values(drops, self._drops_window.new(drops))
        return make_report(self.get_fully_qualified_name(), self.ns, values,
                           ("queue_depth", "dropped_in_window"))

    def status(self) -> dict[str, Any]:
        st = self.assembler.stats
        drops = self.all_drops()
        lag, self._lag_max = self._lag_max, 0.0
        self._lag_worst = max(self._lag_worst, lag)
        return {"version": self.version, "transitions": st.transitions,
                "rollouts": st.rollouts, "gaps": st.gaps,
                "transitions_learned": self.transitions_learned,
                "pending": self.assembler.pending_records, "dropped": drops,
                "missing": dict(st.missing), "resubscribed": self.resubscribed,
                "executor_lag_ms": round(lag * 1e3, 1),
                "executor_lag_max_ms": round(self._lag_worst * 1e3, 1),
                "weights_published": [[v, round(t_end, 4), round(t_pub, 4)]
                                      for v, t_end, t_pub in list(self.updates)]}

    def log_status(self) -> dict[str, Any]:
        s = self.status()
        write_status("trainer", s)
        line = (f"status: version={s['version']} transitions={s['transitions']} "
                f"learned={s['transitions_learned']} rollouts={s['rollouts']} gaps={s['gaps']} "
                f"pending={s['pending']} dropped={s['dropped']}"
                + (f" resubscribed={s['resubscribed']}" if s["resubscribed"] else ""))
        if line != self._last_status:
            self._last_status = line
            self.get_logger().info(line)
        return s

    def status_loop(self) -> None:
        while not self._stop.wait(STATUS_PERIOD_S):
            self.log_status()

    # -- learner results (the learner client's receiver thread): publish and log -------------

    def publish_weights(self, blob: WeightsBlob, end_time: float) -> float:
        """Publish a version; its stamp is when the update that made it ended. Returns the
        seconds to build + publish."""
        t0 = time.perf_counter()
        msg = PolicyWeights(version=blob.version, format=blob.format, sha256=blob.sha256)
        msg.header.stamp = Time(seconds=end_time).to_msg()
        msg.payload = blob.payload  # bytes: ~1000x faster than a NumPy array for uint8[]
        self.weights_pub.publish(msg)
        return time.perf_counter() - t0

    def on_update(self, u: LearnerUpdate) -> None:
        publish_s = self.publish_weights(u.weights, u.end_time)
        self.updates.append((u.version, u.end_time, time.time()))
        self.version, self.transitions_learned = u.version, u.transitions
        for kind, count in u.dropped.items():
            if count > self.learner_dropped.get(kind, 0):
                self.learner_dropped[kind] = count
                self._log_once(kind, f"in the learner offload process: {count} so far")
        for graph in u.hypergraphs:
            self.publish_hypergraph(graph, u.version)
        self.get_logger().info(
            f"update: version={u.version} transitions={u.transitions} "
            f"update_s={u.update_s:.3f} checkpoint_s={u.checkpoint_s:.3f} "
            f"weights_bytes={len(u.weights.payload)} publish_ms={publish_s * 1e3:.1f} "
            f"handover_ms={(time.time() - u.end_time) * 1e3:.1f} "
            f"policy_lag={u.metrics.get('charts/policy_lag', float('nan')):.2f} "
            f"value_loss={u.metrics.get('losses/value_loss', float('nan')):.4g}")

    def on_learner_error(self, message: str) -> None:
        self.get_logger().error(f"{message}; learning stopped at version {self.version}")

    def publish_hypergraph(self, graph: HypergraphSample, version: int) -> None:
        episode, step, skewness, p_h, incidence = graph
        n, m = p_h.shape
        msg = Hypergraph(episode=episode, step=step, num_robots=n, num_hyperedges=m,
                         skewness=skewness, policy_version=version)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.p_h = array.array("f", np.ascontiguousarray(p_h, np.float32).tobytes())
        msg.incidence = incidence.astype(np.uint8).tobytes()
        self.hypergraph_pub.publish(msg)

    def stop(self) -> None:
        """After the executor stopped: stop the learner, settle every pending step (so the last
        status accounts for each), write the last status."""
        self._stop.set()
        self.learner.stop()
        self.status_thread.join(timeout=2.0)
        self.assembler.flush()
        self.log_status()


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: TrainerNode(context), argv,
                    on_stop=lambda node: node.stop() if isinstance(node, TrainerNode) else None)
