"""Multi-process launcher: one YAML file starts a whole sdhn graph, watches it, and stops it.

    python -m sdhn_bringup configs/launch/deploy-tiny.yaml --set episodes=3 --set weights=RUN

Starts the simulator, one actor *process* per robot, the trainer (mode ``train``) and the recorder
(``recorder: true``), each through the ``ros2 run`` shim, all under ``team_ns``, each child's
output in ``<run_dir>/logs/<name>.log``. Every child reads its ROS parameters from one file,
``<run_dir>/params.yaml`` (``--params-file``; each node's entry under its full name,
docs/parameters.md). While it runs it prints a status line (processes ready,
episode, step rate, last success/makespan and return, weights version) and appends every finished
episode to ``<run_dir>/episodes.csv``. Both come as data, never from log text
(:mod:`sdhn_base.ros.status`): a child is ready once its ready file
``<run_dir>/status/<name>.ready`` exists (written by the node runner), and the simulator appends
its events (started, progress, each episode's result) to ``<run_dir>/status/sim-events.jsonl``.
A child that exits is reported; under ``restart.policy: on-failure`` a child that failed (non-zero
exit or killed) is restarted up to ``restart.max_restarts`` times. The run ends when the simulator
finishes its episodes (exit 0), when the simulator fails for good, or on SIGINT/SIGTERM: every child
then gets SIGINT (SIGKILL after ``stop_timeout``), and each exit code is reported. Exit code: 0 when
every child stopped cleanly, 1 when one failed, 2 for an invalid configuration (named field, allowed
values).

Config file fields (every one optional; see :class:`sdhn_bringup.launch_config.LaunchConfig`)::

    env: maif-10          mode: deploy | train       robots: 0 (= the env's team size)
    weights: PATH         (deploy: actor .safetensors, or a run dir holding actor.safetensors)
    seed: 0               episodes: 3 (0 = until stopped)      greedy: true
    temperature: 1.0      (deploy with greedy false: actions from softmax(logits / T))
    break_stalls: false   (deploy with greedy true, MAIF: a robot whose play has stalled samples
                          a few actions; sdhn_policy.stall_breaker)
    stall_rule: ""        (with break_stalls: CALM,PROGRESS,SAMPLE[,T], the rule the actors
                          run; "" = their default. scripts/tune_stall_rule.py chooses one)
    final_approach: false (with break_stalls, MAIF: a robot whose free goal is in its window
                          steps along a shortest free path to it, one on its goal stays unless
                          stall breaking samples; sdhn_policy.final_approach)
    dead_reckoning: null  (deploy, MAIF or RWARE: a robot moves an observation that lags behind
                          its own actions forward by them, sdhn_policy.dead_reckoning; null = as the
                          card beside the weights says, its heldout_large.deploy, false without
                          a card; true / false to choose)
    step_deadline: 1.0    max_steps: 0                         instance: -1
    clock: lockstep | realtime   rate_hz: 10.0   (realtime: the world steps rate_hz times a
                          second with each robot's newest action, never waiting; the actors
                          then act on their newest observation; sdhn_sim.lockstep)
    conditions: {latency: 1, lost_actions: 0.05, ...}   (deployment conditions the simulator
                          applies, sdhn_sim.envs.conditions; {} = the ideal world)
    faults: [{robot: 3, at_step: 40, episode: 0}]   (actor processes SIGKILLed, never restarted,
                          when the simulator reaches that step; it sends them nothing from that
                          step on, sdhn_sim.faults)
    fail_after_missed: 0  (a robot silent this many steps in a row fails: stays as an obstacle,
                          its goal dropped, survivors' success in episodes.csv; 0 = never;
                          faults need >= 1)
    run_dir: runs/...     team_ns: /sdhn                       recorder: true
    recorder: {format: mcap | bag, where: node | sim}   (true = mcap: <run_dir>/recording.mcap,
                          one bare MCAP file; bag: <run_dir>/recording/, a rosbag2 bag
                          directory with recording_0.mcap and metadata.yaml; --set
                          recorder.format=bag. where: node = the recorder node, its own
                          process, every topic of the team; sim = inside the simulator process,
                          the topics it sends and receives (obs, action, state, episode), with
                          no second DDS hop: deploy mode only)
    restart: {policy: never | on-failure, max_restarts: 3, deaf_trainer_s: 60}
                          (deaf_trainer_s: train mode, a trainer whose status stood still that
                          long while the simulator played on is SIGKILLed and restarted under
                          on-failure; 0 = never; sdhn_bringup.trainer_watch)
    managed: false        (true: actors start as unconfigured lifecycle nodes and the launcher
                          drives each one configure -> activate through the standard
                          lifecycle_msgs services, again after a restart; a refused configure,
                          e.g. bad weights, fails the run like an actor's exit 2 does)
    discovery: simple     (simple | server: a Fast DDS discovery server, started first as the
                          child ``discovery`` on 127.0.0.1:discovery_port, 0 = a free port;
                          every other child gets ROS_DISCOVERY_SERVER, the recorder also
                          ROS_SUPER_CLIENT)
    actor_hosts: 0        (0 = one actor process per robot, the default; K: K processes
                          ``actor_host_<k>``, each running a block of the robots' actor nodes
                          on one executor, sdhn_policy.actor_host; unmanaged only)
    start_batch: 0        (0 = every child at once; K: sim, recorder, trainer first, then the
                          actors K at a time, each batch once all started before are ready)
    trainer: {algo: sdhn, rollout_steps: 128, ...}   (mode train; passed through as the
                          trainer node's parameters, which the trainer itself checks: a bad one
                          ends the trainer with exit 2 and one line naming it in its log)
    hosts: {sim: NETNS, actor_0: NETNS, ...}   (tests and demos of robots on separate hosts: the
                          child runs in that existing network namespace via ``ip netns exec``
                          (root), with Fast DDS on UDP only and discovery on the subnet, not
                          localhost; children not named run in the launcher's own namespace)

Relative paths (``weights``, ``run_dir``, ``trainer.config``) written in a launch file resolve
against the repository root when the file lies in a ``configs/launch/`` folder (the shipped
graphs name ``models/...``), else against the file's own folder, so a graph runs the same from
any working directory; paths given with ``--set`` resolve against the current directory, as any
command-line path does.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import ctypes
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Any

import yaml

from sdhn_base.litter import clean_fastdds_shm
from sdhn_base.overrides import OverrideError
from sdhn_base.ros import topics
from sdhn_base.ros.status import READY_ENV, EventReader, read_statuses
from sdhn_bringup.launch_config import (
    RESUME_PARAMETER,
    LaunchConfig,
    describe_actions,
    recording_path,
)
from sdhn_bringup.launch_graph import (
    DISCOVERY_CHILD,
    PARAMS_FILE,
    RESUME_FILE,
    SIM_EVENTS,
    ChildSpec,
    discovery_env,
    graph,
    node_parameters,
    params_file_text,
    status_dir,
)
from sdhn_bringup.launch_load import LaunchConfigError, load_config
from sdhn_bringup.trainer_watch import TrainerWatch
from sdhn_sim.data_files import fastdds_profile
from sdhn_sim.episode import CSV_FIELDS, EpisodeResult

# Managed children: the transition each lifecycle state needs on the way to active, and how long
# a lifecycle request may stay unanswered before it is asked again (from the state).
NEXT_TRANSITION = {"unconfigured": "configure", "inactive": "activate"}
LIFECYCLE_RETRY_S = 5.0
# What a launch writes into its run_dir: a directory holding any of them is another run's and is
# refused (its logs, events and CSV would be read and appended to as this run's). Other files
# (a wrapper's own log, like scripts/soak.py's) do not make it one.
RUN_FILES = ("launch.yaml", PARAMS_FILE, "logs", "status", "episodes.csv", "recording.mcap",
             "recording", "trainer")


def start_stages(children: list[Child], batch: int) -> list[list[Child]]:
    """The order children start in, as stages; each stage starts once every child of the
    earlier ones is ready. The discovery server alone first (a client that starts before its
    server retries, but every retry is start-up time lost); then everything else, or with
    ``batch`` > 0 the other children first and the actors ``batch`` at a time (on a small
    machine a hundred interpreters importing at once take longer than in waves)."""
    first = [c for c in children if c.spec.name == DISCOVERY_CHILD]
    actors = [c for c in children if c.spec.executable in ("actor", "actor_host")
              and c not in first]
    rest = [c for c in children if c not in first and c not in actors]
    if batch <= 0:
        stages = [first, rest + actors]
    else:
        stages = [first, rest, *(actors[k:k + batch] for k in range(0, len(actors), batch))]
    return [stage for stage in stages if stage]


STOP_WAVE = 4
"""Processes stopped together: each one's Fast DDS participant, while it is being deleted,
processes the departures of the others leaving with it, and with dozens leaving at once that
races (measured with 40 actors stopped together, on 2 busy cores: 2-3 of 40 ended by SIGSEGV,
SIGABRT on a corrupted heap, or hung in ``destroy_publisher`` until killed; Fast DDS 2.14,
eProsima/Fast-DDS #6502, #6193). Stopped 4 at a time, each wave once the last has exited."""


def stop_waves(children: list[Child]) -> list[list[Child]]:
    """The simulator (and trainer) first, then the actors in waves of STOP_WAVE."""
    actors = [c for c in children if c.spec.executable in ("actor", "actor_host")]
    rest = [c for c in children if c not in actors]
    return [rest, *(actors[k:k + STOP_WAVE] for k in range(0, len(actors), STOP_WAVE))]


def _die_with_parent() -> None:
    """In the child, before exec: own process group (terminal Ctrl-C reaches only the launcher,
    which then stops the children in order), and SIGTERM if the launcher dies."""
    os.setsid()
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class Child:
    def __init__(self, spec: ChildSpec, log_dir: Path, ready_dir: Path,
                 env: dict[str, str]) -> None:
        self.spec = spec
        self.log_path = log_dir / f"{spec.name}.log"
        self.ready_path = ready_dir / f"{spec.name}.ready"
        self.env = {k: v for k, v in {**env, **spec.env, READY_ENV: str(self.ready_path)}.items()
                    if v}
        self.restarts = 0
        self.proc: subprocess.Popen[bytes] | None = None
        self.log: IO[bytes] | None = None
        self.exit_code: int | None = None
        self.faulted = False  # killed by the fault schedule: expected, never restarted
        # managed: the transition asked for and its reply; "" until asked, "active" once there
        self.lifecycle = ""
        self.lifecycle_reply: Any = None
        self.lifecycle_asked = 0.0  # monotonic time of the pending request
        self.started_wall = 0.0  # wall-clock time of the last start (status files are stamped)

    def start(self) -> None:
        self.lifecycle, self.lifecycle_reply = "", None  # a restarted node starts unconfigured
        self.ready_path.unlink(missing_ok=True)  # written again by this start's node runner
        self.started_wall = time.time()
        self.log = open(self.log_path, "ab")  # noqa: SIM115 - lives as long as the child
        self.proc = subprocess.Popen(self.spec.command(restart=self.restarts > 0), stdout=self.log,
                                     stderr=subprocess.STDOUT, env=self.env,
                                     preexec_fn=_die_with_parent)  # noqa: PLW1509 - no threads
        self.exit_code = None

    @property
    def ready(self) -> bool:
        """Built and spinning: its ready file exists and it has not exited. A child with a
        ``ready_line`` (no node runner to write the file) gets the file from the launcher once
        its log holds the line."""
        if self.exit_code is not None:
            return False
        if self.ready_path.exists():
            return True
        if self.spec.ready_line and self.proc is not None:
            with contextlib.suppress(OSError):
                if self.spec.ready_line in self.log_path.read_text(errors="replace"):
                    self.ready_path.write_text(json.dumps({"node": self.spec.name,
                                                           "pid": self.proc.pid}) + "\n")
                    return True
        return False

    def poll(self) -> int | None:
        if self.proc is None or self.exit_code is not None:
            return self.exit_code
        code = self.proc.poll()
        if code is not None:
            self.exit_code = code
            if self.log is not None:
                self.log.close()
        return code

    def signal(self, sig: int) -> None:
        if self.proc is not None and self.poll() is None:
            self.proc.send_signal(sig)




def node_status_parts(statuses: dict[str, dict[str, Any]]) -> list[str]:
    """What the nodes' status files add to the status line: the trainer's transitions, and every
    node's dropped data per cause (``sdhn_base.ros.status``)."""
    parts = []
    trainer = statuses.get("trainer")
    if trainer is not None:
        parts.append(f"trainer v{trainer.get('version')} {trainer.get('transitions', 0)} "
                     f"transitions ({trainer.get('transitions_learned', 0)} learned)")
    for name, st in statuses.items():
        drops = st.get("dropped") or {}
        if drops:
            parts.append(f"{name} dropped " + ", ".join(f"{k}: {v}" for k, v in
                                                        sorted(drops.items())))
    return parts


FAILED_LOG_LINES = 12  # a failed child's log lines the summary repeats
LOG_LINE_CHARS = 200


def log_tail(path: Path, lines: int) -> list[str]:
    """The last ``lines`` non-empty lines of a child's log, each cut at ``LOG_LINE_CHARS``."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        f.seek(max(0, f.tell() - 64 * 1024))
        text = f.read().decode(errors="replace")
    kept = [line.rstrip() for line in text.splitlines() if line.strip()][-lines:]
    return [line if len(line) <= LOG_LINE_CHARS else line[:LOG_LINE_CHARS] + " [...]"
            for line in kept]


def describe_exit(code: int | None) -> str:
    if code is None:
        return "running"
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit {code}"


TRAINER_WATCH_PERIOD_S = 2.0  # the trainer rewrites its status file this often


class Launcher:
    def __init__(self, cfg: LaunchConfig, out: IO[str] = sys.stdout) -> None:
        self.cfg = cfg
        self.out = out
        self.run_dir = Path(cfg.run_dir).resolve()
        self.log_dir = self.run_dir / "logs"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ)
        env.setdefault("ROS_LOG_DIR", str(self.run_dir / "ros_logs"))
        env["PYTHONUNBUFFERED"] = "1"
        env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
        # Faster participant announcements, so a restarted child matches the others in < 1 s.
        env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(fastdds_profile()))
        if cfg.hosts:
            # Separate hosts: data must cross the network (on one machine Fast DDS would pass it
            # through shared memory, around the namespaces), and discovery must reach the subnet.
            env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
            if env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") in ("", "LOCALHOST"):
                env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        env.update(discovery_env(cfg))
        ready_dir = status_dir(self.run_dir)
        ready_dir.mkdir(parents=True, exist_ok=True)
        self.events = EventReader(ready_dir / SIM_EVENTS)
        self.children = [Child(spec, self.log_dir, ready_dir, env) for spec in graph(cfg)]
        self.stages = start_stages(self.children, cfg.start_batch)
        self.stage_started = 0.0  # monotonic time the last stage was started
        self.stop_requested = False
        self.failed: list[str] = []
        self.t0 = time.monotonic()
        self.episodes: list[dict[str, Any]] = []
        self.step_rate = 0.0
        self.steps_done = 0
        self.t_steps0: float | None = None
        self.position = (0, 0)
        self.trainer_watch = TrainerWatch(cfg.restart.deaf_trainer_s)
        # the same Child object across restarts (train mode only)
        self.trainer = next((c for c in self.children if c.spec.name == "trainer"), None)
        self._next_watch = 0.0
        self._deaf_said = False
        self._tty = out.isatty()
        self.lifecycle: Any = None  # sdhn_base.ros.lifecycle_client.LifecycleClient when managed
        if any(c.spec.managed for c in self.children):
            os.environ.setdefault("ROS_LOG_DIR", env["ROS_LOG_DIR"])
            for key, value in discovery_env(cfg).items():  # the launcher's own participant
                if value:
                    os.environ[key] = value
                else:
                    os.environ.pop(key, None)
            from sdhn_base.ros.lifecycle_client import LifecycleClient  # rclpy only when needed

            self.lifecycle = LifecycleClient("launcher")

    def say(self, text: str) -> None:
        if self._tty:
            self.out.write("\r\033[K")
        self.out.write(f"[launch] {text}\n")
        self.out.flush()

    def status(self) -> str:
        ready = sum(c.ready for c in self.children)
        started = sum(c.proc is not None for c in self.children)
        last = self.episodes[-1] if self.episodes else None
        ep, step = self.position
        parts = [f"{ready}/{len(self.children)} ready"
                 + (f" ({started} started)" if started < len(self.children) else ""),
                 f"episode {ep} step {step}",
                 f"{self.step_rate:.0f} steps/s", f"{len(self.episodes)} episodes done"]
        if last:
            outcome = "completed" if last["completed"] else "not completed"
            parts += [f"last {outcome}, makespan {last['makespan']}, return "
                      f"{float(last['return']):.1f}", f"weights v{last['policy_version']}"]
        parts += node_status_parts(read_statuses(status_dir(self.run_dir)))
        return " | ".join(parts)

    def write_config(self) -> None:
        tmp = self.run_dir / f".launch.yaml.{os.getpid()}.w.tmp"  # sdhn_base.litter
        tmp.write_text(yaml.safe_dump(dataclasses.asdict(self.cfg), sort_keys=False))
        os.replace(tmp, self.run_dir / "launch.yaml")

    def write_params(self) -> None:
        """The run's parameters file, before any child starts (each reads it at start-up), and
        in train mode the one a restarted trainer reads after it."""
        files = {PARAMS_FILE: node_parameters(self.cfg)}
        if self.cfg.mode == "train":
            trainer = topics.absolute(self.cfg.team_ns, "trainer")
            files[RESUME_FILE] = {trainer: {RESUME_PARAMETER: True}}
        for name, nodes in files.items():
            tmp = self.run_dir / f".{name}.{os.getpid()}.w.tmp"  # sdhn_base.litter
            tmp.write_text(params_file_text(nodes))
            os.replace(tmp, self.run_dir / name)

    def read_events(self) -> None:
        """Take the simulator's new events: start of stepping, progress, finished episodes."""
        for event in self.events.new():
            kind = event["event"]
            if kind == "started":
                self.t_steps0 = time.monotonic()
            elif kind == "fault":
                self.kill_for_fault(int(event["robot"]), int(event["episode"]),
                                    int(event["step"]))
            elif kind == "robot_failed":
                self.say(f"robot {event['robot']} failed (silent since episode "
                         f"{event['episode']} step {event['since_step']}): an obstacle from "
                         "there on, its goal dropped")
            elif kind == "progress":
                self.position = (int(event["episode"]), int(event["step"]))
                self.step_rate = float(event["steps_per_s"])
            elif kind == "episode":
                row = EpisodeResult.from_event(event).to_csv_row(time.monotonic() - self.t0)
                self.episodes.append(row)
                self.steps_done += row["length"]
                if self.t_steps0 is not None:
                    self.step_rate = self.steps_done / max(time.monotonic() - self.t_steps0,
                                                           1e-6)
                self.position = (row["episode"] + 1, 0)
                self._append_csv(row)
                outcome = "completed" if row["completed"] else "not completed"
                self.say(f"episode {row['episode']}: {outcome}, makespan {row['makespan']}, "
                         f"return {row['return']}, length {row['length']}, missed "
                         f"{row['missed_actions']}, weights v{row['policy_version']}")

    def watch_trainer(self) -> None:
        """``restart.deaf_trainer_s`` (sdhn_bringup.trainer_watch): a trainer whose status file
        has stood still while the simulator played on hears nothing; under ``on-failure`` it is
        SIGKILLed and the restart path starts a fresh process (a new DDS participant) that
        resumes from the newest checkpoint. Looked at once per trainer status period."""
        now = time.monotonic()
        trainer = self.trainer
        if trainer is None or now < self._next_watch:
            return
        self._next_watch = now + TRAINER_WATCH_PERIOD_S
        if trainer.proc is None or trainer.poll() is not None:
            return
        status = read_statuses(status_dir(self.run_dir)).get("trainer") or {}
        # Only this process's own status counts, once it is ready: until a restarted trainer has
        # written its first one, the file still holds the killed process's frozen counters.
        stamp = status.get("time")
        fresh = (trainer.ready and isinstance(stamp, int | float)
                 and stamp >= trainer.started_wall)
        counters = json.dumps([status.get("transitions"), status.get("pending"),
                               status.get("dropped")], sort_keys=True) if fresh else None
        played = self.steps_done + self.position[1]
        deaf = self.trainer_watch.observe(now, trainer.proc.pid, counters, played)
        if deaf is None:
            return
        what = (f"trainer (pid {trainer.proc.pid}) hears nothing: its transitions, pending "
                f"records and drops stood still for {deaf:.0f}s while the simulator played "
                f"{self.trainer_watch.steps_since(played)} steps")
        can_restart = (self.cfg.restart.policy == "on-failure"
                       and trainer.restarts < self.cfg.restart.max_restarts)
        if can_restart:
            self.say(f"{what}; killing it for a fresh process (restart.deaf_trainer_s)")
            trainer.signal(signal.SIGKILL)
        elif not self._deaf_said:
            self._deaf_said = True
            self.say(f"{what}; not restarted (restart.policy {self.cfg.restart.policy}, "
                     f"{trainer.restarts}/{self.cfg.restart.max_restarts} restarts)")

    def kill_for_fault(self, robot: int, episode: int, step: int) -> None:
        """The fault schedule: SIGKILL the robot's actor, never to restart it."""
        child = next(c for c in self.children if c.spec.name == f"actor_{robot}")
        child.faulted = True
        pid = child.proc.pid if child.proc else "?"
        child.signal(signal.SIGKILL)
        self.say(f"fault schedule: killed actor_{robot} (pid {pid}) at episode {episode} step "
                 f"{step}; not restarted")

    def _append_csv(self, row: dict[str, Any]) -> None:
        path = self.run_dir / "episodes.csv"
        new = not path.exists()
        with open(path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            if new:
                w.writeheader()
            w.writerow(row)

    def on_signal(self, signum: int, _frame: Any) -> None:
        self.stop_requested = True

    def run(self) -> int:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self.on_signal)
        self.write_config()
        self.write_params()
        rec = (("on (in the simulator)" if self.cfg.recorder_where == "sim" else "on")
               if self.cfg.recorder else "off")
        self.say(f"run dir {self.run_dir}; mode {self.cfg.mode}, env {self.cfg.env}, "
                 f"{self.cfg.robots} actor processes (actions {describe_actions(self.cfg)}), "
                 f"recorder {rec}")
        self.start_next_stage()
        next_status = time.monotonic() + self.cfg.status_interval
        finished = False
        all_ready_said = False
        while not self.stop_requested and not finished:
            finished = self.advance_stages()
            if self.lifecycle is not None:
                self.lifecycle.spin(0.1)
                finished = self.drive_managed()
            else:
                time.sleep(0.1)
            self.read_events()
            self.watch_trainer()
            finished = self.check_children() or finished
            if not all_ready_said and all(c.ready for c in self.children):
                # once, at the moment it happens: a short run may end before the next line
                all_ready_said = True
                self.say(self.status())
            elif time.monotonic() >= next_status:
                next_status += self.cfg.status_interval
                if self._tty:
                    self.out.write("\r\033[K" + self.status())
                    self.out.flush()
                else:
                    self.say(self.status())
        if self.stop_requested:
            self.say("stop requested: stopping every child")
        return self.stop_all()

    def start_next_stage(self) -> None:
        stage = self.stages.pop(0)
        for child in stage:
            child.start()
        self.stage_started = time.monotonic()
        total = sum(c.proc is not None for c in self.children)
        self.say(f"started {len(stage)} processes ({total}/{len(self.children)}); logs in "
                 f"{self.log_dir}")
        self.say("pids: " + " ".join(f"{c.spec.name}={c.proc.pid}" for c in stage
                                      if c.proc is not None))

    def advance_stages(self) -> bool:
        """Start the next stage once every child started so far is ready; True (the run ends,
        failed) when a stage is not ready within ``start_timeout``."""
        if not self.stages:
            return False
        waiting = [c for c in self.children if c.proc is not None and not c.ready]
        if not waiting:
            self.start_next_stage()
        elif time.monotonic() - self.stage_started > self.cfg.start_timeout:
            names = ", ".join(c.spec.name for c in waiting[:5]) + (", ..." if len(waiting) > 5
                                                                   else "")
            self.say(f"start_timeout: {len(waiting)} processes not ready after "
                     f"{self.cfg.start_timeout:g}s ({names}); not starting the rest")
            self.failed += [c.spec.name for c in waiting]
            return True
        return False

    def check_children(self) -> bool:
        """Report and restart exited children; True when the run is over."""
        for child in self.children:
            if child.exit_code is not None:
                continue
            code = child.poll()
            if code is None:
                continue
            name = child.spec.name
            if child.faulted:
                self.say(f"{name} ended: {describe_exit(code)} (fault schedule)")
                continue
            if child.spec.essential and code == 0:
                self.say(f"{name} finished ({describe_exit(code)})")
                return True
            self.say(f"{name} (pid {child.proc.pid if child.proc else '?'}) ended: "
                     f"{describe_exit(code)}; log {child.log_path}")
            restart = (self.cfg.restart.policy == "on-failure" and code != 0
                       and child.restarts < self.cfg.restart.max_restarts)
            if restart:
                child.restarts += 1
                child.start()
                self.say(f"restarted {name} ({child.restarts}/{self.cfg.restart.max_restarts}), "
                         f"pid {child.proc.pid if child.proc else '?'}")
                continue
            if code != 0:
                self.failed.append(name)
            if child.spec.essential:
                return True
        return False

    def drive_managed(self) -> bool:
        """Step every managed child towards active through its lifecycle services: ask its state,
        then the transition that state needs (unconfigured: configure, inactive: activate), and
        again, until it is active. A request unanswered for LIFECYCLE_RETRY_S is asked again from
        the state (a restarted child's services may not be matched yet, while the dead one's
        still look ready). True when a child refused a transition (the run cannot start:
        reported like an actor's exit 2)."""
        for child in self.children:
            if not child.spec.managed or child.lifecycle == "active" or not child.ready:
                continue
            node = child.spec.node_name
            reply = child.lifecycle_reply
            if reply is None or (not reply.done()
                                 and time.monotonic() - child.lifecycle_asked > LIFECYCLE_RETRY_S):
                if self.lifecycle.ready(node):
                    child.lifecycle, child.lifecycle_asked = "get_state", time.monotonic()
                    child.lifecycle_reply = self.lifecycle.request_state(node)
                continue
            if not reply.done():
                continue
            result = reply.result()
            if child.lifecycle != "get_state":
                if not result.success:
                    self.say(f"{child.spec.name}: lifecycle {child.lifecycle} of {node} refused; "
                             f"log {child.log_path}")
                    self.failed.append(child.spec.name)
                    return True
                child.lifecycle_reply = None  # ask the state again
                continue
            state = result.current_state.label
            if state == "active":
                child.lifecycle, child.lifecycle_reply = "active", None
                self.say(f"{child.spec.name}: {node} active")
            elif state in NEXT_TRANSITION:
                child.lifecycle, child.lifecycle_asked = NEXT_TRANSITION[state], time.monotonic()
                child.lifecycle_reply = self.lifecycle.request(node, child.lifecycle)
            else:
                child.lifecycle_reply = None  # transitioning: ask again
        return False

    def stop_all(self) -> int:
        # Observers (recorder) stop last so they see everything the others published; the
        # discovery server after them (nobody needs it to leave).
        last = ("recorder", DISCOVERY_CHILD)
        for group in (*stop_waves([c for c in self.children if c.spec.name not in last]),
                      *([c for c in self.children if c.spec.name == name] for name in last)):
            for child in group:
                child.signal(signal.SIGINT)
            deadline = time.monotonic() + self.cfg.stop_timeout
            for child in group:
                if child.proc is None:
                    continue
                try:
                    child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.say(f"{child.spec.name} did not stop in {self.cfg.stop_timeout}s: SIGKILL")
                    child.proc.kill()
                    child.proc.wait()
                child.poll()
        self.read_events()
        if self.lifecycle is not None:
            self.lifecycle.close()
            self.lifecycle = None
        codes = {c.spec.name: c.exit_code for c in self.children if c.proc is not None}
        faulted = {c.spec.name for c in self.children if c.faulted}
        bad = sorted(set(self.failed) | {n for n, c in codes.items() if c != 0} - faulted)
        summary = ", ".join(f"{n}={describe_exit(c)}" for n, c in codes.items())
        self.say(f"exit codes: {summary}")
        restarts = {c.spec.name: c.restarts for c in self.children if c.restarts}
        if restarts:
            self.say(f"restarts: {restarts}")
        self.say(f"{len(self.episodes)} episodes; "
                 + (f"failed: {', '.join(bad)}" if bad else "every child stopped cleanly"))
        for child in self.children:  # why, without opening files (and in a CI log)
            if child.spec.name in bad and child.log_path.exists():
                self.say(f"{child.spec.name}: last lines of {child.log_path}:")
                for line in log_tail(child.log_path, FAILED_LOG_LINES):
                    self.say(f"  {line}")
        recording = recording_path(self.cfg, self.run_dir)
        if recording.exists():
            self.say(f"recording: {recording}")
        return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="launch", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", type=Path, nargs="?", help="launch YAML (see configs/launch/)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a field, e.g. --set episodes=3 --set restart.policy=on-failure")
    p.add_argument("--print-config", action="store_true", help="print the final config and exit")
    p.add_argument("--debug", action="store_true", help="show tracebacks of refused inputs")
    args = p.parse_args(argv)
    try:
        cfg = load_config(args.config, args.set)
    except (LaunchConfigError, OverrideError) as e:
        if args.debug:
            raise
        print(f"launch: invalid configuration: {e}", file=sys.stderr)
        return 2
    if args.print_config:
        print(yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False))
        return 0
    clean_fastdds_shm()  # segments of killed participants (sdhn_base.litter)
    run_dir = Path(cfg.run_dir)
    if run_dir.exists() and (not run_dir.is_dir()
                             or any((run_dir / f).exists() for f in RUN_FILES)):
        print(f"launch: invalid configuration: run_dir: {run_dir} already holds a run; every "
              "run gets its own directory (choose another, or leave run_dir unset for a fresh "
              "one)", file=sys.stderr)
        return 2
    try:
        launcher = Launcher(cfg)
        launcher.write_config()
        launcher.write_params()
    except OSError as e:
        if args.debug:
            raise
        print(f"launch: invalid configuration: run_dir: cannot write {e.filename or run_dir}: "
              f"{e.strerror or e}", file=sys.stderr)
        return 2
    return launcher.run()


if __name__ == "__main__":
    sys.exit(main())
