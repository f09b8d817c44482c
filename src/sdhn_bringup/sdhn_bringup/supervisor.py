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

Config file fields (every one optional; see :class:`LaunchConfig`)::

    env: maif-10          mode: deploy | train       robots: 0 (= the env's team size)
    weights: PATH         (deploy: actor .safetensors, or a run dir holding actor.safetensors)
    seed: 0               episodes: 3 (0 = until stopped)      greedy: true
    temperature: 1.0      (deploy with greedy false: actions from softmax(logits / T))
    break_stalls: false   (deploy with greedy true, MAIF: a robot whose play has stalled samples
                          a few actions; sdhn_policy.stall_breaker)
    stall_rule: ""        (with break_stalls: CALM,PROGRESS,SAMPLE[,T], the rule the actors
                          run; "" = their default. scripts/tune_stall_rule.py chooses one)
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
    restart: {policy: never | on-failure, max_restarts: 3}
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
import itertools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import yaml

from sdhn_base.errors import ConfigError
from sdhn_base.litter import clean_fastdds_shm
from sdhn_base.overrides import OverrideError, set_field
from sdhn_base.ros import topics
from sdhn_base.ros.status import READY_ENV, EventReader, read_statuses
from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_sim.data_files import fastdds_profile
from sdhn_sim.envs.conditions import ConditionsError, conditions_from_dict
from sdhn_sim.envs.registry import RWARE_TASKS, env_names, team_size
from sdhn_sim.episode import CSV_FIELDS, EpisodeResult
from sdhn_sim.faults import FaultsError, faults_text, parse_faults
from sdhn_sim.lockstep import CLOCKS

MODES = ("deploy", "train")
RESTART_POLICIES = ("never", "on-failure")
DISCOVERY_MODES = ("simple", "server")


class LaunchConfigError(ConfigError):
    """Invalid launch configuration; the message names the field and the allowed values."""


@dataclass
class RestartConfig:
    policy: str = "never"  # never | on-failure
    max_restarts: int = 3  # per child


# The trainer section is the trainer node's business: the launcher passes its fields through as
# ROS parameters and knows none of them by name, except that a restarted trainer resumes
# (RESUME_PARAMETER) from the run it started. The graph-wide fields (env, seed, team_ns) and the
# trainer's run_dir are set by the launcher and may not appear in the section.
RESUME_PARAMETER = "resume"
LAUNCHER_SETS = ("env", "seed", "team_ns", "run_dir")
TrainerSection = dict[str, str | int | float | bool]


@dataclass
class LaunchConfig:
    env: str = "maif-tiny"
    mode: str = "deploy"
    robots: int = 0  # 0 = the environment's team size (anything else must equal it)
    weights: str = ""  # deploy: actor weights file or a run directory holding actor.safetensors
    seed: int = 0
    episodes: int = 0  # 0 = until stopped
    greedy: bool = True  # deploy: argmax actions; train mode always samples
    temperature: float = 1.0  # deploy with greedy false: sampling temperature (train mode: 1)
    break_stalls: bool = False  # deploy with greedy true: stall breaking (actor break_stalls)
    stall_rule: str = ""  # with break_stalls: the actors' stall_rule ("" = their default)
    # deploy, MAIF or RWARE: actor dead_reckoning; None = as the weights' card.json says (resolve())
    dead_reckoning: bool | None = None
    step_deadline: float = 1.0
    clock: str = "lockstep"  # lockstep | realtime (the simulator's clock, sdhn_sim.lockstep)
    rate_hz: float = 10.0  # realtime: world steps per second
    conditions: dict[str, Any] = field(default_factory=dict)  # sdhn_sim.envs.conditions fields
    faults: list[dict[str, Any]] = field(default_factory=list)  # sdhn_sim.faults entries
    fail_after_missed: int = 0  # silent steps in a row before a robot fails; 0 = never
    max_steps: int = 0  # 0 = the environment's default
    instance: int = -1
    run_dir: str = ""  # "" = runs/<mode>-<env>-<time>
    team_ns: str = "/sdhn"
    recorder: bool = True
    recorder_format: str = "mcap"  # mcap (a bare .mcap file) | bag (a rosbag2 bag directory)
    recorder_where: str = "node"  # node (the recorder process) | sim (inside the simulator)
    wait_for_observers: bool = True  # the sim waits for trainer/recorder subscriptions at step 0
    start_timeout: float = 60.0
    stop_timeout: float = 10.0  # seconds from SIGINT to SIGKILL when stopping a child
    status_interval: float = 1.0  # seconds between status lines
    restart: RestartConfig = field(default_factory=RestartConfig)
    managed: bool = False  # actors wait for lifecycle transitions, driven by the launcher
    discovery: str = "simple"  # simple (DDS peer-to-peer) | server (a Fast DDS discovery server)
    discovery_port: int = 0  # server: its UDP port on 127.0.0.1 (0 = a free one)
    start_batch: int = 0  # actors started per batch, each after the last is ready (0 = all)
    actor_hosts: int = 0  # 0 = one actor process per robot; K = K processes hosting the robots
    trainer: TrainerSection = field(default_factory=dict)
    hosts: dict[str, str] = field(default_factory=dict)  # child name -> network namespace


WEIGHTS_ALLOWED = ("an actor .safetensors file (with its .json sidecar) or a run directory "
                   "holding actor.safetensors")


def resolve_weights(path: str) -> Path:
    """A weights file from a file path or a run directory (its top-level actor.safetensors).

    Only that one name in a directory: any other pick (the newest, the last in sort order,
    anywhere below) could silently deploy a different run's or an old checkpoint's actor."""
    p = Path(path)
    if p.is_dir():
        candidate = p / "actor.safetensors"
        if candidate.is_file():
            return candidate
        found = sorted(str(q.relative_to(p)) for q in p.glob("**/*.safetensors"))
        hint = f" (it holds {', '.join(found[:3])}{', ...' if len(found) > 3 else ''}: " \
               "name the file)" if found else ""
        raise LaunchConfigError(f"weights: directory {p} has no actor.safetensors{hint}; "
                                f"allowed: {WEIGHTS_ALLOWED}")
    if not p.is_file():
        raise LaunchConfigError(f"weights: {p} does not exist; allowed: {WEIGHTS_ALLOWED}")
    return p


def check_weights_fit(path: Path, env: str) -> None:
    """Refuse weights the actors could not use on ``env`` (observation length, action count,
    one-hot team size), before any process starts."""
    from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file
    from sdhn_sim.envs import make_env

    try:
        spec, _ = decode_weights(load_actor_file(path))
    except WeightsError as e:
        raise LaunchConfigError(f"weights: {path}: {e.reason}") from None
    probe = make_env(env, num_envs=1, seed=0)
    n = team_size(env)
    wrong = [f"{what} {have} (the env has {want})" for what, have, want in (
        ("observation length", spec.obs_size, probe.obs_size),
        ("action count", spec.num_actions, probe.num_actions),
        ("team size", spec.num_robots if spec.use_robot_id else n, n)) if have != want]
    if wrong:
        raise LaunchConfigError(f"weights: {path} does not fit {env}: " + ", ".join(wrong))


NETNS_DIR = Path("/run/netns")
NETNS_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")
"""A name as ``ip netns`` lists it (a file in /run/netns: never a path or '.'/'..')."""


def validate(cfg: LaunchConfig) -> None:
    """Raise LaunchConfigError naming the first bad field; ``cfg`` is left as it is."""
    if cfg.env not in env_names():
        raise LaunchConfigError(f"env: unknown {cfg.env!r}; allowed: {', '.join(env_names())}")
    if cfg.mode not in MODES:
        raise LaunchConfigError(f"mode: got {cfg.mode!r}; allowed: {', '.join(MODES)}")
    if cfg.recorder_format not in RECORDER_FORMATS:
        raise LaunchConfigError(f"recorder.format: got {cfg.recorder_format!r}; allowed: "
                                f"{', '.join(RECORDER_FORMATS)}")
    if cfg.recorder_where not in RECORDER_WHERE:
        raise LaunchConfigError(f"recorder.where: got {cfg.recorder_where!r}; allowed: "
                                f"{', '.join(RECORDER_WHERE)}")
    if cfg.recorder and cfg.recorder_where == "sim" and cfg.mode == "train":
        raise LaunchConfigError("recorder.where: sim records only the simulator's topics, and "
                                "mode train also publishes policy/weights and hypergraph; "
                                "allowed in mode train: node")
    n = team_size(cfg.env)
    if cfg.robots not in (0, n):
        raise LaunchConfigError(f"robots: {cfg.env} has {n} robots, got {cfg.robots}; "
                                f"allowed: 0 or {n}")
    if cfg.mode == "deploy":
        if not cfg.weights:
            raise LaunchConfigError("weights: deploy mode needs an actor weights file or run dir")
        check_weights_fit(resolve_weights(cfg.weights), cfg.env)
    if cfg.restart.policy not in RESTART_POLICIES:
        raise LaunchConfigError(f"restart.policy: got {cfg.restart.policy!r}; allowed: "
                                f"{', '.join(RESTART_POLICIES)}")
    for name in ("seed", "episodes", "max_steps", "restart.max_restarts"):
        obj: Any = cfg
        for part in name.split("."):
            obj = getattr(obj, part)
        if obj < 0:
            raise LaunchConfigError(f"{name}: must be >= 0, got {obj}")
    if not (isinstance(cfg.temperature, (int, float)) and not isinstance(cfg.temperature, bool)
            and 0.01 <= cfg.temperature <= 100.0):
        raise LaunchConfigError(f"temperature: got {cfg.temperature!r}; allowed: a number in "
                                "[0.01, 100] (sampled deployment, greedy: false)")
    if cfg.temperature != 1.0 and (cfg.mode != "deploy" or cfg.greedy):
        raise LaunchConfigError("temperature: applies only to deploy mode with greedy: false "
                                "(train mode samples the policy itself; greedy takes the argmax)")
    if cfg.break_stalls and (cfg.mode != "deploy" or not cfg.greedy):
        raise LaunchConfigError("break_stalls: applies only to deploy mode with greedy: true "
                                "(sampled play has no standstill to break)")
    if cfg.break_stalls and cfg.env in RWARE_TASKS:
        raise LaunchConfigError(f"break_stalls: reads MAIF observations; {cfg.env} is an RWARE "
                                "task")
    if cfg.stall_rule:
        from sdhn_policy.stall_breaker import StallRule

        if not cfg.break_stalls:
            raise LaunchConfigError("stall_rule: applies only with break_stalls: true")
        try:
            StallRule.parse(cfg.stall_rule)
        except ValueError as e:
            raise LaunchConfigError(f"stall_rule: {e}") from None
    if cfg.dead_reckoning and cfg.mode != "deploy":
        raise LaunchConfigError(f"dead_reckoning: applies only to deploy mode; got mode "
                                f"{cfg.mode}")
    if cfg.clock not in CLOCKS:
        raise LaunchConfigError(f"clock: got {cfg.clock!r}; allowed: {', '.join(CLOCKS)}")
    if not (isinstance(cfg.rate_hz, int | float) and 0 < cfg.rate_hz <= 1000):
        raise LaunchConfigError(f"rate_hz: got {cfg.rate_hz!r}; allowed: steps per second in "
                                "(0, 1000]")
    try:
        conditions_from_dict(cfg.conditions, n, maif=cfg.env.startswith("maif"))
        faults = parse_faults(cfg.faults, n, cfg.episodes)
    except (ConditionsError, FaultsError) as e:
        raise LaunchConfigError(str(e)) from None
    if faults and cfg.actor_hosts:
        raise LaunchConfigError("faults: kill one robot's actor process; allowed: only with "
                                "actor_hosts: 0 (one process per robot)")
    if cfg.fail_after_missed < 0 or (faults and cfg.fail_after_missed == 0):
        raise LaunchConfigError(f"fail_after_missed: got {cfg.fail_after_missed}; allowed: 0 "
                                "(never) or silent steps >= 1 (faults need >= 1, e.g. 3)")
    for name in ("step_deadline", "start_timeout", "stop_timeout", "status_interval"):
        if not getattr(cfg, name) > 0:
            raise LaunchConfigError(f"{name}: must be > 0 seconds, got {getattr(cfg, name)}")
    try:
        topics.check_team_ns(cfg.team_ns)
    except topics.NamespaceError as e:
        raise LaunchConfigError(str(e)) from None
    if cfg.discovery not in DISCOVERY_MODES:
        raise LaunchConfigError(f"discovery: got {cfg.discovery!r}; allowed: "
                                f"{', '.join(DISCOVERY_MODES)}")
    if not 0 <= cfg.discovery_port <= 65535:
        raise LaunchConfigError(f"discovery_port: got {cfg.discovery_port}; allowed: 0 (a free "
                                "port) or a UDP port 1..65535")
    if cfg.discovery == "server" and cfg.hosts:
        raise LaunchConfigError("discovery: the discovery server listens on 127.0.0.1, not "
                                "across hosts; allowed: simple when hosts is set")
    if not 0 <= cfg.actor_hosts <= n:
        raise LaunchConfigError(f"actor_hosts: got {cfg.actor_hosts}; allowed: 0 (one actor "
                                f"process per robot) to {n} (processes hosting the robots)")
    if cfg.actor_hosts and cfg.managed:
        raise LaunchConfigError("managed: an actor host runs unmanaged actors only; allowed: "
                                "false when actor_hosts > 0")
    if cfg.start_batch < 0:
        raise LaunchConfigError(f"start_batch: must be >= 0 (0 = every actor at once), got "
                                f"{cfg.start_batch}")
    if cfg.managed and cfg.hosts:
        raise LaunchConfigError("managed: the launcher drives lifecycle services from its own "
                                "network namespace, not across hosts; allowed: false when hosts "
                                "is set")
    names = [c.name for c in graph(dataclasses.replace(cfg, robots=n, run_dir=".", hosts={}))]
    for child, netns in cfg.hosts.items():
        if child not in names:
            raise LaunchConfigError(f"hosts.{child}: no such child; allowed: {', '.join(names)}")
        if not NETNS_NAME.fullmatch(netns) or netns in (".", "..") or not (
                NETNS_DIR / netns).is_file():
            raise LaunchConfigError(f"hosts.{child}: no network namespace {netns!r}; allowed: "
                                    "one listed by `ip netns list`")
    for key, value in cfg.trainer.items():
        if key in LAUNCHER_SETS:
            raise LaunchConfigError(f"trainer.{key}: set by the launcher; allowed: any other "
                                    "trainer parameter (the top-level field sets this one)")
        if not isinstance(value, str | int | float | bool):
            raise LaunchConfigError(f"trainer.{key}: expected a scalar, got {value!r}")


def resolve(cfg: LaunchConfig) -> LaunchConfig:
    """A validated config with the derived fields filled in (a new object): the team size, the
    weights file found in a run directory, the default run directory, dead reckoning as the
    weights' card says when the config leaves it unset."""
    weights = resolve_weights(cfg.weights).resolve() if cfg.mode == "deploy" else None
    return dataclasses.replace(
        cfg,
        robots=team_size(cfg.env),
        weights=str(weights) if weights is not None else "",
        dead_reckoning=card_dead_reckoning(weights, cfg.env) if cfg.dead_reckoning is None
        else cfg.dead_reckoning,
        run_dir=cfg.run_dir or f"runs/{cfg.mode}-{cfg.env}-{time.strftime('%Y%m%d-%H%M%S')}",
        discovery_port=(cfg.discovery_port or free_udp_port()) if cfg.discovery == "server"
        else cfg.discovery_port,
    )


def card_dead_reckoning(weights: Path | None, env: str) -> bool:
    """Whether the card.json beside deploy weights names dead reckoning in its deployment mode
    (no card, or a card it cannot read: False, the actors' default)."""
    from sdhn_policy.deploy_contract import card_dead_reckoning as says

    card = weights.parent / "card.json" if weights is not None else None
    if card is None or not card.is_file():
        return False
    try:
        return says(json.loads(card.read_text()))
    except (OSError, ValueError, AttributeError):
        return False


def describe_actions(cfg: LaunchConfig) -> str:
    """How the actors choose their actions under ``cfg``, in words (the launcher's first line
    and the demo say it, so neither can claim another mode than the one that runs)."""
    if cfg.mode != "deploy":
        return "sampled from the policy being trained"
    reckon = ", with dead reckoning" if cfg.dead_reckoning else ""
    if not cfg.greedy:
        return f"sampled at temperature {cfg.temperature:g}{reckon}"
    if cfg.break_stalls:
        rule = cfg.stall_rule or "the actors' default"
        return f"greedy, with stall breaking (rule {rule}){reckon}"
    return "greedy" + reckon


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing holds now (the kernel's pick), for the discovery
    server: runs side by side (tests, several users) never share one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def set_trainer(cfg: LaunchConfig, key: str, value: Any) -> None:
    """One field of the pass-through trainer section (``trainer.KEY`` or a ``trainer:`` map)."""
    if not key or "." in key:
        raise LaunchConfigError(f"trainer.{key}: expected trainer.PARAMETER")
    cfg.trainer[key] = value


PATH_FIELDS = ("weights", "run_dir")
TRAINER_PATH_FIELDS = ("config",)  # the trainer node's config YAML


def file_base(path: Path) -> Path:
    """The folder a launch file's relative paths resolve against: the repository root for a
    file in ``<root>/configs/launch/``, else the file's own folder."""
    folder = path.resolve().parent
    if folder.name == "launch" and folder.parent.name == "configs":
        return folder.parent.parent
    return folder


def anchored(value: Any, base: Path) -> Any:
    """``value`` made absolute against ``base`` when it is a non-empty relative path (``~``
    expanded); anything else (unset, absolute, not a string) as it is, for validation to judge."""
    if not isinstance(value, str) or not value:
        return value
    return str(base / Path(value).expanduser())  # an absolute path stays itself


RECORDER_FORMATS = ("mcap", "bag")
RECORDER_WHERE = ("node", "sim")
RECORDER_KEYS = ("enabled", "format", "where")


def set_recorder(cfg: LaunchConfig, value: Any, key: str = "") -> None:
    """``recorder: true|false``, ``recorder: {format: bag, enabled: true}`` or (``--set``)
    ``recorder.format=bag``: a mapping turns the recorder on unless it says ``enabled: false``."""
    if key:
        value = {key: value}
    if not isinstance(value, dict):
        set_field(cfg, "recorder", value)
        return
    unknown = [str(k) for k in value if str(k) not in RECORDER_KEYS]
    if unknown:
        raise LaunchConfigError(f"recorder.{unknown[0]}: unknown field; allowed: "
                                f"{', '.join(RECORDER_KEYS)}")
    if "format" in value:
        cfg.recorder_format = str(value["format"])
    if "where" in value:
        cfg.recorder_where = str(value["where"])
    set_field(cfg, "recorder", value.get("enabled", True))


def recorder_node(cfg: LaunchConfig) -> bool:
    """Whether the run has the recorder node (else no recording, or the simulator records)."""
    return cfg.recorder and cfg.recorder_where == "node"


def recording_path(cfg: LaunchConfig, run: Path) -> Path:
    """Where the recorder writes: a bare file, or a bag directory (recorder_node's rule: an
    output not ending in .mcap is a rosbag2 bag directory)."""
    return run / ("recording" if cfg.recorder_format == "bag" else "recording.mcap")


def set_block(cfg: LaunchConfig, key: str, value: Any) -> None:
    """The ``conditions`` mapping or the ``faults`` list, whole (checked by ``validate``)."""
    want = dict if key == "conditions" else list
    if value in (None, ""):
        value = want()
    if not isinstance(value, want):
        raise LaunchConfigError(f"{key}: expected a {'mapping' if want is dict else 'list'}, "
                                f"got {value!r}")
    setattr(cfg, key, value)


def load_config(path: Path | None, overrides: list[str]) -> LaunchConfig:
    cfg = LaunchConfig()
    if path is not None:
        try:
            data = load_yaml(path, what="config") or {}
        except YamlError as e:  # unreadable, binary, malformed, a duplicate key, an alias bomb
            raise LaunchConfigError(str(e)) from None
        if not isinstance(data, dict):
            raise LaunchConfigError(f"config: {path} must hold a mapping of fields")
        base = file_base(path)
        for k, v in data.items():
            if str(k) == "hosts":
                if not isinstance(v, dict):
                    raise LaunchConfigError(f"hosts: expected a mapping, got {v!r}")
                cfg.hosts.update({str(hk): str(hv) for hk, hv in v.items()})
            elif str(k) == "recorder":
                set_recorder(cfg, v)
            elif str(k) in ("conditions", "faults"):
                set_block(cfg, str(k), v)
            elif str(k) == "trainer":
                if not isinstance(v, dict):
                    raise LaunchConfigError(f"trainer: expected a mapping, got {v!r}")
                for tk, tv in v.items():
                    set_trainer(cfg, str(tk),
                                anchored(tv, base) if str(tk) in TRAINER_PATH_FIELDS else tv)
            else:
                set_field(cfg, str(k), anchored(v, base) if str(k) in PATH_FIELDS else v)
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise LaunchConfigError(f"--set {item!r}: expected FIELD=VALUE")
        try:
            parsed = load_yaml(value, what=f"--set {key.strip()}") if value.strip() else ""
        except YamlError:
            parsed = value  # not YAML: the text itself, checked by the field's type
        if key.strip().startswith("hosts."):
            cfg.hosts[key.strip().removeprefix("hosts.")] = str(parsed)
        elif key.strip() in ("conditions", "faults"):
            set_block(cfg, key.strip(), parsed)
        elif key.strip().startswith("conditions."):
            cfg.conditions[key.strip().removeprefix("conditions.")] = parsed
        elif key.strip().startswith("trainer."):
            set_trainer(cfg, key.strip().removeprefix("trainer."), parsed)
        elif key.strip() == "recorder" or key.strip().startswith("recorder."):
            set_recorder(cfg, parsed, key.strip().removeprefix("recorder").removeprefix("."))
        else:
            set_field(cfg, key.strip(), parsed)
    validate(cfg)
    return resolve(cfg)


# --- children ---------------------------------------------------------------------------------


# Every node's parameters go into one ROS parameters file per run (rcl's format: the node's full
# name, then ros__parameters), passed to each child with --params-file; the file stays in the
# run directory as the record of what every node was started with (docs/parameters.md).
PARAMS_FILE = "params.yaml"
# A restarted trainer also reads this one (written in train mode): rcl gives a value in a later
# file precedence for the same node name, while a -p value would lose to params.yaml's entry.
RESUME_FILE = "params-resume.yaml"
NodeParameters = dict[str, dict[str, Any]]  # node full name -> parameter name -> value


def actor_node(ns: str, robot: int) -> str:
    """The full name of robot ``robot``'s actor node ('/sdhn/robot_3/actor')."""
    return topics.absolute(topics.absolute(ns, topics.robot(robot)), "actor")


def node_parameters(cfg: LaunchConfig) -> NodeParameters:
    """The parameters of every node of one run, by node full name, in start order."""
    ns, run = cfg.team_ns, Path(cfg.run_dir).resolve()  # ns checked by validate()
    nodes: NodeParameters = {}
    if recorder_node(cfg):
        nodes[topics.absolute(ns, "recorder")] = {
            "team_ns": ns, "output": str(recording_path(cfg, run))}
    if cfg.mode == "train":
        nodes[topics.absolute(ns, "trainer")] = {
            "team_ns": ns, "env": cfg.env, "seed": cfg.seed, "run_dir": str(run / "trainer"),
            **cfg.trainer}
    extra = ((int(recorder_node(cfg)) + int(cfg.mode == "train")) if cfg.wait_for_observers
             else 0)
    nodes[topics.absolute(ns, "sim")] = {
        "env": cfg.env, "seed": cfg.seed, "episodes": cfg.episodes,
        "step_deadline": float(cfg.step_deadline), "instance": cfg.instance,
        "start_timeout": float(cfg.start_timeout), "max_steps": cfg.max_steps,
        "extra_subscribers": extra, "events_file": str(status_dir(run) / SIM_EVENTS),
        "recording": (str(recording_path(cfg, run))
                      if cfg.recorder and cfg.recorder_where == "sim" else ""),
        "clock": cfg.clock, "rate_hz": float(cfg.rate_hz),
        "conditions": yaml.safe_dump(cfg.conditions, default_flow_style=True).strip()
        if cfg.conditions else "",
        "faults": faults_text(parse_faults(cfg.faults, cfg.robots, cfg.episodes)),
        "fail_after_missed": cfg.fail_after_missed}
    for i in range(cfg.robots):
        nodes[actor_node(ns, i)] = {
            "team_ns": ns, "robot_id": i, "num_robots": cfg.robots,
            "weights_file": cfg.weights if cfg.mode == "deploy" else "",
            "greedy": cfg.greedy if cfg.mode == "deploy" else False, "seed": cfg.seed,
            "temperature": float(cfg.temperature),
            "break_stalls": bool(cfg.break_stalls and cfg.mode == "deploy"),
            **({"stall_rule": cfg.stall_rule} if cfg.stall_rule else {}),
            "env": cfg.env, "managed": cfg.managed, "realtime": cfg.clock == "realtime",
            "dead_reckoning": bool(cfg.dead_reckoning and cfg.mode == "deploy")}
    return nodes


def params_file_text(nodes: NodeParameters) -> str:
    """The parameters file of a run (YAML types: a string stays a string, 1.0 a double)."""
    head = ("# Written by the launcher: every node's parameters for this run, passed with\n"
            "# --ros-args --params-file (docs/parameters.md).\n")
    return head + yaml.safe_dump({name: {"ros__parameters": values}
                                  for name, values in nodes.items()}, sort_keys=False)


@dataclass
class ChildSpec:
    name: str
    package: str
    executable: str
    ros_args: list[str]
    essential: bool = False  # the graph ends when this child ends (the simulator)
    restart_args: list[str] = field(default_factory=list)  # appended when it is restarted
    netns: str = ""  # run inside this network namespace ("" = the launcher's own)
    managed: bool = False  # a lifecycle node the launcher drives to active
    argv: list[str] = field(default_factory=list)  # a program that is no ROS node: its command
    env: dict[str, str] = field(default_factory=dict)  # set for this child ("" = unset it)
    ready_line: str = ""  # no node runner: ready once its log holds this text

    @property
    def node_name(self) -> str:
        """The fully qualified ROS name of its node (its namespace from ``-r __ns:=``)."""
        ns = next((a.removeprefix("__ns:=") for a in self.ros_args if a.startswith("__ns:=")),
                  "")
        return f"{ns}/{self.executable}"

    def command(self, restart: bool = False) -> list[str]:
        """The package's console script next to this interpreter (what ``ros2 run`` runs from
        ``lib/<package>``), else the ``ros2 run`` shim, which finds it by package metadata
        (~0.1 s more start-up per process). A restart adds ``restart_args`` (resume:=true)."""
        ros_args = [*self.ros_args, *(self.restart_args if restart else [])]
        host = ["ip", "netns", "exec", self.netns] if self.netns else []
        if self.argv:
            return [*host, *self.argv]
        script = Path(sys.executable).parent / self.executable
        if script.is_file() and _entry_package(script) == self.package:
            return [*host, str(script), "--ros-args", *ros_args]
        return [*host, sys.executable, "-m", "sdhn_bringup.ros2_cli", "run", self.package,
                self.executable, "--ros-args", *ros_args]


def _entry_package(script: Path) -> str | None:
    """The top-level package a pip console script imports its entry point from."""
    m = re.search(r"^from (\w+)[.\w]* import", script.read_text(errors="replace"), re.M)
    return m.group(1) if m else None


def graph(cfg: LaunchConfig) -> list[ChildSpec]:
    """The children of one run, in start order; each reads its parameters from the run's
    parameters file (``node_parameters``, written by ``Launcher.write_params``)."""
    ns, run = cfg.team_ns, Path(cfg.run_dir).resolve()  # ns checked by validate()
    params = ["--params-file", str(run / PARAMS_FILE)]
    children: list[ChildSpec] = []
    if cfg.discovery == "server":
        children.append(discovery_server(cfg.discovery_port))
    if recorder_node(cfg):
        # The recorder finds its topics in the graph (get_topic_names_and_types): a plain client
        # of a discovery server learns only the endpoints that match its own, a super client all.
        children.append(ChildSpec("recorder", "sdhn_sim", "recorder",
                                  ["-r", f"__ns:={ns}", *params],
                                  env={SUPER_CLIENT_ENV: "TRUE"} if cfg.discovery == "server"
                                  else {}))
    if cfg.mode == "train":
        # A restarted trainer continues from its last checkpoint (without resume it would refuse
        # the run_dir its first start filled, exit 2, and never come back).
        children.append(ChildSpec("trainer", "sdhn_train", "trainer",
                                  ["-r", f"__ns:={ns}", *params],
                                  restart_args=["--params-file", str(run / RESUME_FILE)]))
    # The simulator names its topics relative to its namespace, the team namespace.
    children.append(ChildSpec("sim", "sdhn_sim", "sim", ["-r", f"__ns:={ns}", *params],
                              essential=True))
    if cfg.actor_hosts:
        children += actor_hosts(cfg.robots, cfg.actor_hosts, ns, params)
    for i in range(0 if cfg.actor_hosts else cfg.robots):
        children.append(ChildSpec(f"actor_{i}", "sdhn_policy", "actor", [
            "-r", f"__ns:={topics.absolute(ns, topics.robot(i))}", *params],
            managed=cfg.managed))
    for child in children:
        child.netns = cfg.hosts.get(child.name, "")
    return children


def actor_hosts(robots: int, hosts: int, ns: str, params: list[str]) -> list[ChildSpec]:
    """``hosts`` actor host processes (sdhn_policy.actor_host), ``actor_host_<k>``, each
    running a contiguous block of the robots (sizes differ by one at most)."""
    bounds = [robots * k // hosts for k in range(hosts + 1)]
    return [ChildSpec(f"actor_host_{k}", "sdhn_policy", "actor_host", params,
                      argv=[sys.executable, "-m", "sdhn_policy.actor_host", "--team-ns", ns,
                            "--robots", f"{a}:{b}", "--ros-args", *params])
            for k, (a, b) in enumerate(itertools.pairwise(bounds))]


DISCOVERY_CHILD = "discovery"
DISCOVERY_SERVER_ENV = "ROS_DISCOVERY_SERVER"
SUPER_CLIENT_ENV = "ROS_SUPER_CLIENT"
DISCOVERY_READY_LINE = "Server is running"
DISCOVERY_SERVER_PROGRAM = "fast-discovery-server"


def discovery_env(cfg: LaunchConfig) -> dict[str, str]:
    """What every ROS process of a run needs in its environment for ``cfg.discovery``: with the
    server, ``ROS_DISCOVERY_SERVER`` (Fast DDS 2.14 reads it and turns each participant that
    would use simple discovery into a client of that server, ignoring
    ``ROS_AUTOMATIC_DISCOVERY_RANGE``); with simple discovery, neither variable from the caller
    (a stray one would make a run silently wait for a server that is not there)."""
    if cfg.discovery == "server":
        return {DISCOVERY_SERVER_ENV: f"127.0.0.1:{cfg.discovery_port}", SUPER_CLIENT_ENV: ""}
    return {DISCOVERY_SERVER_ENV: "", SUPER_CLIENT_ENV: ""}


def discovery_server(port: int) -> ChildSpec:
    """The Fast DDS discovery server (the ``fast-discovery-server`` tool of the Fast DDS wheel,
    next to this interpreter), server id 0 on 127.0.0.1:``port``; ready when it says so."""
    program = Path(sys.executable).parent / DISCOVERY_SERVER_PROGRAM
    return ChildSpec(DISCOVERY_CHILD, "fastrtps", DISCOVERY_SERVER_PROGRAM, [],
                     argv=[str(program), "-i", "0", "-l", "127.0.0.1", "-p", str(port)],
                     env={DISCOVERY_SERVER_ENV: "", SUPER_CLIENT_ENV: ""},
                     ready_line=DISCOVERY_READY_LINE)


def status_dir(run_dir: Path) -> Path:
    """Where the children's ready files and the simulator's events go."""
    return run_dir / "status"


SIM_EVENTS = "sim-events.jsonl"
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

    def start(self) -> None:
        self.lifecycle, self.lifecycle_reply = "", None  # a restarted node starts unconfigured
        self.ready_path.unlink(missing_ok=True)  # written again by this start's node runner
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


def describe_exit(code: int | None) -> str:
    if code is None:
        return "running"
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit {code}"


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
