"""Simulator node ``sdhn_sim sim``: one environment stepped in lock-step with N actor processes.

Runs in the team namespace (``/sdhn``, or ``-r __ns:=/other``) and names its topics relative to it
(:mod:`sdhn_base.ros.topics`): publishes ``robot_<i>/obs`` (one per robot), ``state`` and
``episode``; subscribes to every ``robot_<i>/action``. Before step 0 it waits
until every obs topic has a subscriber (plus ``extra_subscribers``) and every action topic a
publisher, then: publish step t, wait for the N actions of step t or ``step_deadline`` (missing ->
stay, counted, logged), step, publish step t+1. The lock-step logic lives in
:mod:`sdhn_sim.lockstep`; this file only moves messages. After ``episodes`` episodes (0 = never) it
stops by itself with exit code 0; it exits 1 when the actors are not all matched within
``start_timeout``. With ``events_file`` set it also appends its events (started, progress, each
episode's result, done, and its totals when it stops) to that file as JSON lines for a supervisor
(:mod:`sdhn_base.ros.status`).

With ``clock:=realtime`` the world does not wait: once every robot has answered step 0 (the same
start handshake), a timer steps it ``rate_hz`` times a second with each robot's newest action
not yet applied, or 'stay' (:mod:`sdhn_sim.lockstep` defines what is applied and counted). Each
episode event then also holds the staleness counts of the applied actions; ``/diagnostics`` shows
them, with the ticks the timer ran late.

Beside ours, two standard streams (docs/lifecycle-and-diagnostics.md): ``poses``
(``geometry_msgs/PoseArray``, every robot's cell centre in frame ``map``, 1 cell = 1 m, robot i
at index i; each step, only while someone subscribes) and ``/diagnostics`` (step rate, missed
actions, drops per cause, 1 Hz)."""

from __future__ import annotations

import array
import dataclasses
import functools
import signal
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, PoseArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.serialization import serialize_message
from rclpy.timer import Timer

from sdhn_base.diagnostics import Report, WindowCounts, drop_values, make_report
from sdhn_base.drops import DropKind
from sdhn_base.ros import cdr, topics
from sdhn_base.ros.diagnostics import DiagnosticsPublisher
from sdhn_base.ros.params import INT_MAX, declare, floating, integer, string
from sdhn_base.ros.qos import POSES, STEP
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_base.ros.status import EventWriter
from sdhn_msgs.msg import EpisodeSummary, RobotAction, RobotObservation, TeamState
from sdhn_sim.envs.registry import env_names, team_size
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.faults import FaultsError, parse_faults
from sdhn_sim.lockstep import Frame, LockstepSim, SimConfig, SimConfigError
from sdhn_sim.poses import FRAME_ID, cell_center
from sdhn_sim.recording.queued import QueuedRecording, graph_offers
from sdhn_sim.recording.reader import fresh_path

LOG_EVERY_S = 2.0  # period of the progress line
# Until every robot has answered the first step, its observation is re-sent to the silent ones this
# often (or every step_deadline, if shorter): a long deadline (tests that compare lock-step runs
# exactly use 60 s) must not make an actor whose action writer matched the simulator late wait
# that long and then be counted as missed. Not shorter: an actor still loading at a busy start
# would answer the first step twice.
HANDSHAKE_RESEND_S = 5.0


# The parameters, typed and ranged (they mirror SimConfig; SimConfig.validate checks the rest).
def _parameter(f: dataclasses.Field[Any]) -> tuple[Any, ParameterDescriptor]:
    """(default, descriptor) of the ROS parameter mirroring SimConfig field ``f``."""
    meta = f.metadata
    if meta["text_default"] is not None:  # a structured setting, given as YAML text
        return meta["text_default"], string(meta["help"])
    default = f.default
    if isinstance(default, bool | str):
        return default, string(meta["help"])
    lo, hi = meta["lo"], meta["hi"]
    if isinstance(default, int):
        return default, integer(meta["help"], int(lo) if lo is not None else -INT_MAX,
                                int(hi) if hi is not None else INT_MAX)
    return default, floating(meta["help"], float(lo), float(hi))


# Every SimConfig field, generated (one definition of each setting), and what only the node has.
PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    **{f.name: _parameter(f) for f in dataclasses.fields(SimConfig)},
    "events_file": ("", string("JSON-lines file for a supervisor's events; '' = none")),
    "recording": ("", string(
        "record what this simulator sends and receives (every robot's obs and action, state, "
        "episode) into this .mcap file, or a rosbag2 bag directory (a path not ending in "
        ".mcap), inside this process: no recorder node needed for these topics; '' = none "
        "(an existing file or directory is never overwritten: -1, -2... is appended)")),
}
NODE_ONLY = ("events_file", "recording")
OBS_TYPE, ACTION_TYPE = "sdhn_msgs/msg/RobotObservation", "sdhn_msgs/msg/RobotAction"
STATE_TYPE, EPISODE_TYPE = "sdhn_msgs/msg/TeamState", "sdhn_msgs/msg/EpisodeSummary"


def sim_config(p: dict[str, Any]) -> SimConfig:
    """The core's config from the declared parameters (types already checked by ROS); the
    ``conditions`` text is parsed here (SimConfigError naming the bad field)."""
    values = {k: v for k, v in p.items() if k in SimConfig.__dataclass_fields__}
    values["conditions"] = SimConfig.parse_conditions(p.get("conditions", ""))
    if str(p.get("env")) in env_names():  # else SimConfig.validate names the env
        try:
            values["faults"] = parse_faults(p.get("faults", ""), team_size(str(p["env"])),
                                            int(p.get("episodes", 0)))
        except FaultsError as e:
            raise SimConfigError(str(e)) from e
    return SimConfig(**values)


class SimNode(Node):
    def __init__(self, context: Context) -> None:
        # The team namespace is the node's: /sdhn unless remapped (-r __ns:=/other).
        super().__init__("sim", namespace=topics.DEFAULT_TEAM_NS, context=context)
        topics.check_team_ns(self.get_namespace(), "namespace (the simulator's, -r __ns:=...)")
        p = declare(self, PARAMETERS)
        try:
            self.sim = LockstepSim(sim_config(p))
        except SimConfigError as e:
            raise ConfigError(str(e)) from e
        self.cfg = cfg = self.sim.cfg
        self.events = EventWriter(str(p["events_file"]))
        self.exit_code = 0
        n = self.sim.num_robots
        self.obs_pubs = [self.create_publisher(RobotObservation, topics.robot_obs(i), STEP)
                         for i in range(n)]
        self.state_pub = self.create_publisher(TeamState, topics.STATE, STEP)
        self.episode_pub: Publisher = self.create_publisher(EpisodeSummary, topics.EPISODE, STEP)
        self.action_subs = [
            self.create_subscription(RobotAction, topics.robot_action(i),
                                     functools.partial(self.on_action, i), STEP, raw=True)
            for i in range(n)]
        # Each robot's observation is written straight as CDR (sdhn_base.ros.cdr) and published
        # as bytes: no message object filled through its checked setters, no conversion to C,
        # and the bytes are what the in-process recording writes.
        self._obs_writers = [cdr.ObservationWriter(i, n, self.sim.obs_size, FRAME_ID)
                             for i in range(n)]
        self._obs_topics = [p.topic_name for p in self.obs_pubs]
        self._action_topics = [s.topic_name for s in self.action_subs]
        self.recording = self.open_recording(str(p["recording"]))
        self._state_msg = TeamState(env_name=cfg.env, num_robots=n)
        self._state_msg.header.frame_id = "map"
        self.poses_pub = self.create_publisher(PoseArray, topics.POSES, POSES)
        self._poses_msg = PoseArray(poses=[Pose() for _ in range(n)])
        self._poses_msg.header.frame_id = FRAME_ID
        self.drops: Counter[str] = Counter()
        self.started = False
        # Until every robot has answered the first step, that step is re-sent to the silent
        # robots (every HANDSHAKE_RESEND_S) instead of stepping with 'stay' at the deadline:
        # matching is only visible from the sim's side, so an actor may not yet receive from (or
        # reach) a sim that already sees it.
        self.handshake = True
        self.stepping = False  # between the first published step and the end
        self.realtime_timer: Timer | None = None
        self.t_last_tick = 0.0
        self.late_ticks = 0  # realtime: ticks that came over 1.5 periods after the previous one
        self.t_start = time.monotonic()
        self.deadline = float("inf")
        self.resend_at = float("inf")  # the start handshake's next re-send of the first step
        self.steps_total = 0
        self.t_last_log = 0.0
        self.steps_at_last_log = 0
        self._missed_logged_episode = -1
        period = min(0.01, cfg.step_deadline / 4)
        self.tick: Timer = self.create_timer(period, self.on_tick)
        self._window = (time.monotonic(), 0, 0)  # (time, steps_total, missed) at the last report
        self._drops_window = WindowCounts()
        self.diagnostics = DiagnosticsPublisher(self, self.diagnostics_report)
        self.get_logger().info(
            f"ready: env={cfg.env} robots={n} obs_size={self.sim.obs_size} seed={cfg.seed} "
            f"episodes={cfg.episodes} step_deadline={cfg.step_deadline}s clock={cfg.clock}"
            + (f" rate_hz={cfg.rate_hz:g}" if cfg.realtime else "") + " "
            f"conditions: {cfg.conditions.label()} "
            f"ns={self.get_namespace()}; waiting for "
            f"{n} actors")

    def open_recording(self, output: str) -> QueuedRecording | None:
        """The in-process recording (parameter ``recording``), as the recorder node names and
        writes its file: same schemas, channels, QoS metadata and ``rosbag2`` record."""
        if not output:
            return None
        requested = Path(output)
        bag_dir = requested.suffix != ".mcap"
        if bag_dir and not requested.name.strip("."):
            raise ConfigError(f"recording: {output!r}; allowed: '' (none), a path ending in "
                              ".mcap, or a bag directory to create")
        where = fresh_path(requested)
        path = where / f"{where.name}_0.mcap" if bag_dir else where
        contract = {t: STEP for t in [*self._obs_topics, *self._action_topics,
                                      self.state_pub.topic_name, self.episode_pub.topic_name]}
        try:
            recording = QueuedRecording(
                path, bag_dir, lambda topic: graph_offers(self, topic, contract[topic])
                or ([contract[topic]], ""), self.get_logger().error)
        except OSError as e:
            raise ConfigError(f"recording: cannot write {path}: {e}") from e
        note = "" if where == requested else f" ({requested} exists)"
        self.get_logger().info(f"recording this simulator's topics to {path}{note}")
        return recording

    # -- start-up and deadline ---------------------------------------------------------------

    def all_matched(self) -> bool:
        extra = self.cfg.extra_subscribers
        # Every endpoint of an extra subscriber (trainer, recorder) matches on its own: its
        # episode subscription can match after its obs and state ones, and a short run's
        # summaries published before then would be lost to it.
        return (all(p.get_subscription_count() >= 1 + extra for p in self.obs_pubs)
                and self.state_pub.get_subscription_count() >= extra
                and self.episode_pub.get_subscription_count() >= extra
                and all(s.get_publisher_count() >= 1 for s in self.action_subs))

    def on_tick(self) -> None:
        now = time.monotonic()
        if not self.started:
            if self.all_matched():
                self.started = True
                self.get_logger().info(
                    f"all {self.sim.num_robots} actors matched after {now - self.t_start:.2f}s; "
                    "starting episode 0")
                self.t_start = self.t_last_log = now
                self.events.write("started", robots=self.sim.num_robots,
                                  reward=self.sim.env.reward_name)
                self.publish(self.sim.reset())
            elif now - self.t_start > self.cfg.start_timeout:
                self.get_logger().error(
                    f"start_timeout: not every actor matched within {self.cfg.start_timeout}s "
                    f"(obs subscribers {[p.get_subscription_count() for p in self.obs_pubs]}, "
                    f"action publishers {[s.get_publisher_count() for s in self.action_subs]})")
                self.finish(1)
            return
        if self.handshake and now - self.t_start < self.cfg.start_timeout:
            if now >= self.resend_at:
                self.resend_first_step()
        elif now >= self.deadline and self.cfg.realtime:
            self.start_realtime()  # start_timeout passed: the silent robots stay from here on
        elif now >= self.deadline:
            if self._missed_logged_episode != self.sim.episode:
                self._missed_logged_episode = self.sim.episode
                self.get_logger().warning(
                    f"step deadline {self.cfg.step_deadline}s passed at episode "
                    f"{self.sim.episode} step {self.sim.step}: robots {self.sim.missing()} take "
                    "'stay' (logged once per episode; every miss is counted in "
                    "TeamState.missed_actions and the episode summary)")
            self.advance()
        if now - self.t_last_log >= LOG_EVERY_S:
            rate = (self.steps_total - self.steps_at_last_log) / (now - self.t_last_log)
            self.events.write("progress", episode=self.sim.episode, step=self.sim.step,
                              steps_per_s=rate, missed=self.sim.total_missed)
            self.get_logger().info(f"progress: episode {self.sim.episode} step {self.sim.step} "
                                   f"{rate:.0f} steps/s missed={self.sim.total_missed}")
            self.t_last_log, self.steps_at_last_log = now, self.steps_total

    # -- lock-step -----------------------------------------------------------------------------

    def on_action(self, robot: int, data: bytes) -> None:
        # Raw CDR read at its offsets (sdhn_base.ros.cdr): no Python message per action.
        if self.recording is not None:  # every message on the topic, as a recorder receives it
            now = time.time_ns()
            self.recording.put(self._action_topics[robot], ACTION_TYPE, data, now, now)
        if not self.stepping:
            self.drop(DropKind.NOT_STARTED,
                      f"action from robot {robot} before step 0 or after the end")
            return
        try:
            msg = cdr.read_action(data)
        except cdr.CdrError as e:
            self.drop(DropKind.UNDECODABLE, f"robot {robot}'s action: {e}")
            return
        rid = msg.robot_id
        if rid != robot:
            self.drop(DropKind.UNKNOWN_ROBOT, f"robot_id {rid} on robot {robot}'s action topic")
            return
        kind = self.sim.submit(rid, msg.episode, msg.step, msg.action, msg.policy_version)
        if kind is not None:
            self.drop(kind, f"robot {rid} episode {msg.episode} step {msg.step} action "
                      f"{msg.action}; now at episode {self.sim.episode} step {self.sim.step}")
        elif self.sim.complete and (not self.cfg.realtime or self.handshake):
            if self.cfg.realtime:
                self.start_realtime()
            else:
                self.advance()

    def resend_first_step(self) -> None:
        frame, silent = self.sim.frame, self.sim.missing()
        assert frame is not None
        now = time.time_ns()
        for i in silent:
            if not self.sim.cut[i]:
                self.send_observation(frame, i, now)
        self.get_logger().info(f"first step: no answer yet from robots {silent}; re-sent")
        self.deadline = time.monotonic() + self.cfg.step_deadline
        self.resend_at = self.next_resend()

    def next_resend(self) -> float:
        """When the start handshake next re-sends the first step to the silent robots."""
        return time.monotonic() + min(self.cfg.step_deadline, HANDSHAKE_RESEND_S)

    def start_realtime(self) -> None:
        """End of the start handshake: step 0 now, then every 1 / rate_hz seconds."""
        self.handshake = False
        self.deadline = float("inf")
        self.t_last_tick = time.monotonic()
        self.realtime_timer = self.create_timer(1.0 / self.cfg.rate_hz, self.on_realtime_tick)
        self.advance()

    def on_realtime_tick(self) -> None:
        now = time.monotonic()
        if now - self.t_last_tick > 1.5 / self.cfg.rate_hz:
            self.late_ticks += 1
        self.t_last_tick = now
        self.advance()

    def advance(self) -> None:
        self.handshake = False
        frame, result = self.sim.advance()
        self.steps_total += 1
        self.publish(frame)
        if result is not None:
            self.publish_summary(result)
            if self.sim.finished:
                elapsed = time.monotonic() - self.t_start
                self.events.write("done", episodes=self.sim.episodes_done,
                                  steps=self.steps_total, elapsed_s=elapsed)
                self.get_logger().info(
                    f"done: {self.sim.episodes_done} episodes, {self.steps_total} steps in "
                    f"{elapsed:.2f}s ({self.steps_total / elapsed:.1f} steps/s), "
                    f"{self.sim.total_missed} missed actions, drops {dict(self.drops)}")
                self.finish(0)
                return
            self.publish(self.sim.reset())

    def publish(self, f: Frame) -> None:
        self.stepping = True
        self.write_sim_events()
        # The wall clock the node's ROS clock reads (no simulated time in this graph), without
        # rclpy's Time objects: the stamp of every message of this step and its recording time.
        now = time.time_ns()
        for i in range(self.sim.num_robots):
            if not self.sim.cut[i]:  # a scheduled fault: this robot is sent nothing more
                self.send_observation(f, i, now)
        # TeamState is for observers (trainer, recorder, viz); a deployment without them has no
        # reader of it. A volatile message goes only to readers matched at publish time, so
        # skipping it while none is matched changes nothing a subscriber can see, and saves
        # filling, serialising and handing one message of N+1 to DDS every step.
        # The in-process recording holds every state.
        readers = self.state_pub.get_subscription_count()
        if readers or self.recording is not None:
            self.publish_state(f, now, readers > 0)
        if self.poses_pub.get_subscription_count():  # the same reasoning
            sec, nanosec = divmod(now, 1_000_000_000)
            self.publish_poses(f, Time(sec=sec, nanosec=nanosec))
        self.deadline = (float("inf") if f.done or (self.cfg.realtime and not self.handshake)
                         else time.monotonic() + self.cfg.step_deadline)
        self.resend_at = self.next_resend() if self.handshake and not f.done else float("inf")

    def publish_state(self, f: Frame, now_ns: int, send: bool) -> None:
        """TeamState of frame f: sent when ``send``, recorded when recording."""
        s = self._state_msg
        s.header.stamp.sec, s.header.stamp.nanosec = divmod(now_ns, 1_000_000_000)
        s.episode, s.step = f.episode, f.step
        s.state = array.array("f", np.ascontiguousarray(f.state, dtype=np.float32).tobytes())
        s.positions = array.array("i", f.positions.astype(np.int32).tobytes())
        s.team_reward, s.terminated, s.truncated = float(f.reward), f.terminated, f.truncated
        s.makespan_so_far, s.missed_actions = f.step, f.missed
        s.instance_id = f.instance_id
        data = serialize_message(s)
        if send:
            self.state_pub.publish(data)
        if self.recording is not None:
            self.recording.put(self.state_pub.topic_name, STATE_TYPE, data, now_ns, now_ns)

    def publish_poses(self, f: Frame, stamp: Time) -> None:
        """Every robot's cell centre (the viewer's convention, sdhn_sim.poses), robot i at i."""
        m = self._poses_msg
        m.header.stamp = stamp
        for pose, (x, y) in zip(m.poses, f.positions.tolist(), strict=True):
            pose.position.x, pose.position.y = cell_center(x, y)
        self.poses_pub.publish(m)

    def diagnostics_report(self) -> Report:
        now, steps, missed = time.monotonic(), self.steps_total, self.sim.total_missed
        t0, steps0, missed0 = self._window
        self._window = (now, steps, missed)
        d_steps, d_missed = steps - steps0, missed - missed0
        robot_steps = d_steps * self.sim.num_robots
        values: dict[str, float | int | str] = {
            "episode": self.sim.episode, "step": self.sim.step,
            "steps_per_s": d_steps / max(now - t0, 1e-9),
            "steps": steps, "episodes_done": self.sim.episodes_done,
            "missed_actions": missed, "missed_actions_in_window": d_missed,
            "missed_fraction_in_window": d_missed / robot_steps if robot_steps else 0.0,
        }
        values["clock"] = self.cfg.clock
        # the deployment conditions and what they did since start (sdhn_sim.envs.conditions),
        # and the robots failed for silence over ROS (killed actors, fault schedule)
        values["conditions"] = self.cfg.conditions.label()
        values |= {f"conditions/{k}": v for k, v in self.sim.conditions.counts.items()}
        values |= {"failed_robots_now": int(self.sim.conditions.failed[0].sum()),
                   "silent_robots_failed": self.sim.ros_failures,
                   "fault_cuts": int(self.sim.cut.sum())}
        if self.cfg.realtime:
            rt = self.sim.staleness
            values |= {"rate_hz": self.cfg.rate_hz, "late_ticks": self.late_ticks,
                       "stale_actions": rt.stale, "mean_staleness": rt.mean,
                       "superseded_actions": rt.superseded, "expired_actions": rt.expired}
            values |= {f"staleness/{k}": c for k, c in sorted(rt.applied.items())}
        values |= drop_values(self.drops, self._drops_window.new(self.drops))
        judged: tuple[str, ...] = ("missed_actions_in_window", "missed_fraction_in_window",
                                   "dropped_in_window")
        note = "" if self.started else f"waiting for {self.sim.num_robots} actors"
        rec = self.recording
        if rec is not None:  # the in-process recording, judged as the recorder node's
            values |= {"recording": str(rec.path), "messages_written": rec.writer.messages_written,
                       "write_queue_depth": rec.queue_depth, "not_written": rec.not_written}
            judged += ("write_queue_depth", "not_written")
            if rec.error:
                note = f"recording stopped: {rec.error}"
        return make_report(self.get_fully_qualified_name(), self.get_namespace(), values,
                           judged, note)

    def send_observation(self, f: Frame, i: int, now_ns: int) -> None:
        """Publish (and record) robot i's observation of frame f, stamped ``now_ns``."""
        data = self._obs_writers[i].write(now_ns, f.episode, f.step, f.obs[i],
                                          reward=float(f.reward), terminated=bool(f.terminated),
                                          truncated=bool(f.truncated),
                                          obs_age=int(f.obs_age[i]) if f.obs_age is not None
                                          else 0)
        self.obs_pubs[i].publish(data)
        if self.recording is not None:
            self.recording.put(self._obs_topics[i], OBS_TYPE, data, now_ns, now_ns)

    def publish_summary(self, r: EpisodeResult) -> None:
        m = r.to_message(EpisodeSummary())
        now = time.time_ns()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(now, 1_000_000_000)
        data = serialize_message(m)
        self.episode_pub.publish(data)
        if self.recording is not None:
            self.recording.put(self.episode_pub.topic_name, EPISODE_TYPE, data, now, now)
        self.events.write("episode", **r.to_event(), **self.realtime_event())
        self.get_logger().info(
            f"episode {r.episode} done: makespan={r.makespan_text} length={r.length} "
            f"return={r.episode_return:.2f} collisions={r.collisions} missed={r.missed_actions} "
            f"policy_version={r.policy_version}")

    def write_sim_events(self) -> None:
        """The core's fault cuts and silent-robot failures, as events and log lines."""
        for e in self.sim.take_events():
            self.events.write(e.pop("event"), **e)
            if "since_step" in e:
                self.get_logger().warning(
                    f"robot {e['robot']} failed: silent for {e['silent_steps']} steps since "
                    f"episode {e['episode']} step {e['since_step']} (stays as an obstacle, its "
                    "goal dropped)")
            else:
                self.get_logger().warning(
                    f"fault schedule: robot {e['robot']} is sent no more observations from "
                    f"episode {e['episode']} step {e['step']} (its actor is to be killed)")

    def realtime_event(self, total: bool = False) -> dict[str, Any]:
        """The realtime counts an episode event (or, ``total``, the stop event) carries."""
        if not self.cfg.realtime:
            return {}
        counts = self.sim.staleness if total else self.sim.ep_staleness
        return {"clock": "realtime", "rate_hz": self.cfg.rate_hz, **counts.to_event(),
                **({"late_ticks": self.late_ticks} if total else {})}

    def close_recording(self) -> None:
        """Write what is queued and finish the file (summary, index, ``rosbag2`` record)."""
        rec = self.recording
        if rec is None:
            return
        lost = rec.close()
        if rec.error is not None:
            self.get_logger().error(f"recording incomplete ({rec.error}); {lost} messages not "
                                    "written")
        self.get_logger().info(f"closed {rec.path}: {rec.writer.messages_written} messages in "
                               f"{rec.batches} batches (largest {rec.largest_batch}); writer "
                               f"thread {rec.writer_cpu_s * 1e3:.1f} ms of CPU")

    def drop(self, kind: str, detail: str) -> None:
        self.drops[kind] += 1
        if self.drops[kind] == 1:
            self.get_logger().warning(f"dropped action ({kind}): {detail} (logged once per kind)")

    def finish(self, code: int) -> None:
        """Stop the node: flush the summaries to their subscribers, then end the spin loop."""
        self.exit_code = code
        self.tick.cancel()
        if self.realtime_timer is not None:
            self.realtime_timer.cancel()
        self.stepping = False
        self.deadline = float("inf")
        self.episode_pub.wait_for_all_acked(Duration(seconds=2))
        # run_node's own stop path (flag set by its SIGTERM handler): the spin loop ends, on_stop
        # runs, the process ends with exit_code (run_node's EXIT_CODE).
        signal.raise_signal(signal.SIGTERM)


def _on_stop(node: Node) -> None:
    if isinstance(node, SimNode):
        # Also as data: a supervisor or test counts the steps of a run stopped mid-episode.
        node.events.write("stopped", steps=node.steps_total, missed=node.sim.total_missed,
                          drops=dict(node.drops), **node.realtime_event(total=True))
        node.get_logger().info(f"totals: {node.steps_total} steps, {node.sim.total_missed} "
                               f"missed actions, drops {dict(node.drops)}")
        node.close_recording()


def main(argv: Sequence[str] | None = None) -> int:
    # The exit code is the node's exit_code (run_node's EXIT_CODE) once it ran.
    return run_node(lambda context, _args: SimNode(context), argv, _on_stop)
