"""Trainer node: the centralised learner of the ROS deployment (``sdhn_train trainer``).

Subscribes to every robot's obs and action and to ``state`` (N from the env), assembles team
transitions by (episode, step) (``sdhn_train.transitions``), and every ``rollout_steps``
transitions runs the algorithm's learner, the same as the in-process trainer's, on a worker thread
(``sdhn_train.stream_learner``). After each update: checkpoint (atomic) -> publish weights
version + 1 (LATCHED) -> publish sampled hypergraphs (SENSOR, SDHN only). Version 1 (or the
resumed version) is published at start so actors can begin.

Parameters (typed, with descriptors): env and algo (a name of the env / algorithm registry), seed
(>= 0), run_dir ("" = runs/<env>__<algo>__<seed>__ros-<time>), rollout_steps (>= 2), config
("" = defaults; YAML of the in-process trainer config), resume, team_ns. The YAML's
env/algo/seed/rollout length are replaced by the parameters; the ROS stream is one environment,
so env.num_envs and ppo.num_minibatches are 1. Checking them, merging the config and resuming are
plain functions below; the constructor only declares.
"""

from __future__ import annotations

import array
import functools
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import IntegerRange, ParameterDescriptor
from rclpy.context import Context
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from sdhn_msgs.msg import (
    EpisodeSummary,
    Hypergraph,
    PolicyWeights,
    RobotAction,
    RobotObservation,
    TeamState,
)
from sdhn_sim.envs.api import BatchedEnv, EpisodeStats
from sdhn_sim.envs.registry import env_names, make_env
from sdhn_sim.ros import topics
from sdhn_sim.ros.qos import LATCHED, SENSOR, STEP
from sdhn_sim.ros.runner import ConfigError, run_node
from sdhn_train import checkpoint as ckpt
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.config import Config, apply_dict, load_yaml, validate
from sdhn_train.config import ConfigError as TrainConfigError
from sdhn_train.env_features import resolve_features, wrap_features
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import NonFiniteLossError
from sdhn_train.runs import MetricsLog, episode_metrics
from sdhn_train.stream_learner import HypergraphSample, StreamLearner
from sdhn_train.transitions import AssembledRollout, TransitionAssembler

QUEUE_ROLLOUTS = 4  # rollouts waiting for the learner; beyond that the oldest is dropped
HYPERGRAPHS_PER_UPDATE = 8
STATUS_PERIOD_S = 5.0


@dataclass(frozen=True)
class TrainerParams:
    env: str = "maif-10"
    algo: str = "sdhn"
    seed: int = 1
    run_dir: str = ""
    rollout_steps: int = 128
    config: str = ""
    resume: bool = False
    team_ns: str = "/sdhn"


def _descriptors() -> dict[str, ParameterDescriptor]:
    def d(text: str, constraints: str = "", low: int | None = None) -> ParameterDescriptor:
        desc = ParameterDescriptor(description=text, additional_constraints=constraints,
                                   read_only=True)
        if low is not None:
            desc.integer_range = [IntegerRange(from_value=low, to_value=2**31 - 1, step=1)]
        return desc

    return {
        "env": d("environment", f"one of {', '.join(env_names())}"),
        "algo": d("algorithm", f"one of {', '.join(ALGO_NAMES)}"),
        "seed": d("seed of everything", "an integer >= 0", low=0),
        "run_dir": d("run directory; '' = runs/<env>__<algo>__<seed>__ros-<time>", "a path"),
        "rollout_steps": d("team steps per update", "an integer >= 2", low=2),
        "config": d("YAML of the in-process trainer config; '' = defaults", "a YAML file or ''"),
        "resume": d("continue from the newest checkpoint in run_dir", "true or false"),
        "team_ns": d("namespace of the team's topics", "an absolute namespace like /sdhn"),
    }


def declare_parameters(node: Node) -> TrainerParams:
    """Declare every parameter with its descriptor; a value of the wrong type or out of range is
    a ConfigError naming the parameter and what is allowed."""
    defaults = TrainerParams()
    values: dict[str, Any] = {}
    for name, desc in _descriptors().items():
        try:
            values[name] = node.declare_parameter(name, getattr(defaults, name), desc).value
        except (InvalidParameterTypeException, InvalidParameterValueException) as e:
            detail = str(e).splitlines()[0].split("Reason: ")[-1].removesuffix(f": {name}")[:160]
            raise ConfigError(f"{name}: {detail}; allowed: {desc.additional_constraints}"
                              ) from None
    return TrainerParams(**values)


def check_params(p: TrainerParams) -> None:
    """The checks a descriptor cannot express: registry names and the namespace rule."""
    if p.env not in env_names():
        raise ConfigError(f"env: {p.env!r} is unknown; allowed: {', '.join(env_names())}")
    if p.algo not in ALGO_NAMES:
        raise ConfigError(f"algo: {p.algo!r} is unknown; allowed: {', '.join(ALGO_NAMES)}")
    if not topics.is_team_ns(p.team_ns):  # the one namespace rule (sdhn_sim.ros.topics)
        raise ConfigError(f"team_ns: {p.team_ns!r}; allowed: {topics.TEAM_NS_RULE}")


def build_config(env: str, algo: str, seed: int, rollout_steps: int, config_path: str) -> Config:
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
    cfg.log.progress = False
    try:
        validate(cfg)
    except TrainConfigError as e:
        raise ConfigError(f"config: {e}") from e
    return cfg


def open_learner(p: TrainerParams, cfg: Config) -> tuple[StreamLearner, BatchedEnv, Path | None]:
    """(learner, env, the checkpoint resumed from or None) for the node's run_dir; a fresh run
    writes its version-1 checkpoint. ConfigError for a run_dir that cannot be used."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(p.run_dir or f"runs/{p.env}__{p.algo}__{p.seed}__ros-{stamp}")
    if ckpt.latest_checkpoint(run_dir) is not None and not p.resume:
        raise ConfigError(f"run_dir: {run_dir} holds checkpoints of an earlier run; "
                          "allowed: resume:=true, or an empty or new run_dir")
    env = make_env(cfg.env.name, num_envs=1, seed=cfg.train.seed)
    learner_env = wrap_features(env, resolve_features(cfg))  # the learner sees features
    learner = StreamLearner(cfg, EnvInfo.of(learner_env), run_dir)
    try:
        resumed = learner.resume_latest() if p.resume else None
    except (ckpt.CheckpointError, KeyError, ValueError, RuntimeError) as e:
        raise ConfigError(f"resume: the newest checkpoint in {run_dir} cannot be loaded "
                          f"({str(e)[:200]}); allowed: a run_dir with a valid checkpoint, "
                          "or resume:=false with a new run_dir") from e
    if resumed is None:
        learner.save_checkpoint()
    return learner, env, resumed


class TrainerNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("trainer", context=context)
        p = declare_parameters(self)
        check_params(p)
        cfg = build_config(p.env, p.algo, p.seed, p.rollout_steps, p.config)
        self.learner, env, resumed = open_learner(p, cfg)
        self.run_dir = self.learner.run_dir
        self.info = EnvInfo.of(env)  # raw sizes, as the messages carry them
        self.ns = p.team_ns
        n = self.info.num_robots
        self.assembler = TransitionAssembler(n, self.info.obs_size, self.info.state_size,
                                             self.info.num_actions,
                                             rollout_steps=cfg.ppo.rollout_len,
                                             max_steps=env.max_steps)
        self.dropped: dict[str, int] = {}
        self._rollouts: queue.Queue[AssembledRollout] = queue.Queue(maxsize=QUEUE_ROLLOUTS)
        self._stop = threading.Event()
        self._episodes: list[EpisodeSummary] = []
        self._episodes_lock = threading.Lock()
        self._last_status = ""

        self.weights_pub = self.create_publisher(
            PolicyWeights, topics.absolute(self.ns, topics.WEIGHTS), LATCHED)
        self.hypergraph_pub = self.create_publisher(
            Hypergraph, topics.absolute(self.ns, topics.HYPERGRAPH), SENSOR)
        for i in range(n):
            self.create_subscription(RobotObservation,
                                     topics.absolute(self.ns, topics.robot_obs(i)),
                                     functools.partial(self.on_obs, i), STEP)
            self.create_subscription(RobotAction,
                                     topics.absolute(self.ns, topics.robot_action(i)),
                                     functools.partial(self.on_action, i), STEP)
        self.create_subscription(TeamState, topics.absolute(self.ns, topics.STATE), self.on_state,
                                 STEP)
        self.create_subscription(EpisodeSummary, topics.absolute(self.ns, topics.EPISODE),
                                 self.on_episode, STEP)
        self.create_timer(STATUS_PERIOD_S, self.log_status)

        self.publish_weights()
        self.worker = threading.Thread(target=self.learn_loop, name="learner", daemon=True)
        self.worker.start()
        how = f"resumed from {resumed.name}" if resumed else "fresh"
        self.get_logger().info(
            f"ready: env={cfg.env.name} algo={cfg.algo.name} robots={n} "
            f"rollout_steps={cfg.ppo.rollout_len} version={self.learner.version} ({how}) "
            f"run_dir={self.run_dir}")

    # -- callbacks (executor thread): validate, hand to the assembler, queue rollouts --------

    def _drop(self, kind: str | None, topic: str, detail: str) -> None:
        if kind is None:
            return
        self.dropped[kind] = self.dropped.get(kind, 0) + 1
        if self.dropped[kind] == 1:
            self.get_logger().warning(
                f"dropped a message on {topic}: {kind} ({detail}); counting, logged once per kind")

    def on_obs(self, robot: int, m: RobotObservation) -> None:
        topic = topics.absolute(self.ns, topics.robot_obs(robot))
        if m.robot_id != robot:
            self._drop("robot id differs from the topic's robot", topic, f"robot_id={m.robot_id}")
            return
        obs = _floats(m.obs)
        reason = self.assembler.add_obs(m.episode, m.step, m.robot_id, obs,
                                        num_robots=m.num_robots, terminated=m.terminated,
                                        truncated=m.truncated)
        self._drop(reason, topic, f"episode {m.episode} step {m.step} len {obs.size}")
        self._queue_ready()

    def on_action(self, robot: int, m: RobotAction) -> None:
        topic = topics.absolute(self.ns, topics.robot_action(robot))
        if m.robot_id != robot:
            self._drop("robot id differs from the topic's robot", topic, f"robot_id={m.robot_id}")
            return
        reason = self.assembler.add_action(m.episode, m.step, m.robot_id, m.action,
                                           log_prob=m.log_prob, version=m.policy_version)
        self._drop(reason, topic, f"episode {m.episode} step {m.step} action {m.action} "
                   f"log_prob {m.log_prob}")
        self._queue_ready()

    def on_state(self, m: TeamState) -> None:
        state = _floats(m.state)
        reason = self.assembler.add_state(m.episode, m.step, state, num_robots=m.num_robots,
                                          team_reward=m.team_reward, terminated=m.terminated,
                                          truncated=m.truncated)
        self._drop(reason, topics.absolute(self.ns, topics.STATE),
                   f"episode {m.episode} step {m.step} "
                   f"len {state.size}")
        self._queue_ready()

    def on_episode(self, m: EpisodeSummary) -> None:
        with self._episodes_lock:
            self._episodes.append(m)

    def _queue_ready(self) -> None:
        while (ready := self.assembler.pop_rollout()) is not None:
            try:
                self._rollouts.put_nowait(ready)
            except queue.Full:
                self._rollouts.get_nowait()
                self._rollouts.put_nowait(ready)
                self._drop("rollout dropped (learner busy)", "learner",
                           f"{QUEUE_ROLLOUTS} rollouts were waiting")

    def log_status(self) -> None:
        st = self.assembler.stats
        drops = {**self.dropped, **st.dropped}
        line = (f"status: version={self.learner.version} transitions={st.transitions} "
                f"rollouts={st.rollouts} gaps={st.gaps} pending={self.assembler.pending_records} "
                f"dropped={drops}")
        if line != self._last_status:
            self._last_status = line
            self.get_logger().info(line)

    # -- learning (worker thread) -------------------------------------------------------------

    def publish_weights(self) -> tuple[int, float]:
        """Publish the current version; returns (payload bytes, seconds to build + publish)."""
        t0 = time.perf_counter()
        blob = self.learner.weights()
        msg = PolicyWeights(version=blob.version, format=blob.format, sha256=blob.sha256)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.payload = blob.payload
        self.weights_pub.publish(msg)
        return len(blob.payload), time.perf_counter() - t0

    def learn_loop(self) -> None:
        log = MetricsLog(self.run_dir, self.learner.cfg.log.tensorboard)
        try:
            while not self._stop.is_set():
                try:
                    assembled = self._rollouts.get(timeout=0.1)
                except queue.Empty:
                    continue
                try:
                    result = self.learner.train(assembled, HYPERGRAPHS_PER_UPDATE)
                except NonFiniteLossError as e:
                    self.get_logger().error(f"{e}; training stopped at version "
                                            f"{self.learner.version}, last checkpoint kept")
                    return
                size, publish_s = self.publish_weights()
                for g in result.hypergraphs:
                    self.publish_hypergraph(g, result.version)
                with self._episodes_lock:
                    episodes, self._episodes = self._episodes, []
                metrics = dict(result.metrics)
                metrics.update(episode_metrics("charts", [_stats(e) for e in episodes]))
                metrics["perf/update_s"] = result.update_s
                metrics["perf/checkpoint_s"] = result.checkpoint_s
                metrics["perf/weights_publish_s"] = publish_s
                log.write(self.learner.transitions, metrics)
                self.get_logger().info(
                    f"update: version={result.version} transitions={self.learner.transitions} "
                    f"update_s={result.update_s:.3f} checkpoint_s={result.checkpoint_s:.3f} "
                    f"weights_bytes={size} publish_ms={publish_s * 1e3:.1f} "
                    f"policy_lag={metrics['charts/policy_lag']:.2f} "
                    f"value_loss={metrics.get('losses/value_loss', float('nan')):.4g}")
        finally:
            log.close()

    def publish_hypergraph(self, g: HypergraphSample, version: int) -> None:
        n, m = g.p_h.shape
        msg = Hypergraph(episode=g.episode, step=g.step, num_robots=n, num_hyperedges=m,
                         skewness=g.skewness, policy_version=version)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.p_h = array.array("f", np.ascontiguousarray(g.p_h, np.float32).tobytes())
        msg.incidence = g.incidence.astype(np.uint8).tobytes()
        self.hypergraph_pub.publish(msg)

    def stop(self) -> None:
        self._stop.set()
        self.worker.join(timeout=4.0)
        self.log_status()


def _floats(values: Any) -> np.ndarray:
    """A float32[] field (array.array) as a NumPy view, without a per-element copy."""
    return np.frombuffer(values, dtype=np.float32) if len(values) else np.zeros(0, np.float32)


def _stats(m: EpisodeSummary) -> EpisodeStats:
    return EpisodeStats(0, float(m.episode_return), int(m.length),
                        int(m.makespan) if m.completed else None, bool(m.completed),
                        int(m.collisions), float(m.formation_error))


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: TrainerNode(context), argv,
                    on_stop=lambda node: node.stop() if isinstance(node, TrainerNode) else None)
