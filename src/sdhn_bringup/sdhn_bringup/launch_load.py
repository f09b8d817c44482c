"""Reading a launch configuration: a launch file and ``--set`` overrides into a checked, resolved
:class:`~sdhn_bringup.launch_config.LaunchConfig` (:func:`load_config`).

Relative paths in a file are anchored to its folder (or the repository root for
``configs/launch/``), each field is checked before anything starts (:func:`validate`: one
:class:`LaunchConfigError` naming the field and what is allowed; the weights are decoded and
matched to the env), and :func:`resolve` fills in what follows (the team size, the weights file of a
run directory, the run directory, dead reckoning from the weights' card, the discovery port).
It stands above :mod:`sdhn_bringup.launch_graph`: ``hosts`` may name only children of the graph.
"""

from __future__ import annotations

import dataclasses
import json
import re
import socket
import time
from pathlib import Path
from typing import Any

from sdhn_base.errors import ConfigError
from sdhn_base.overrides import set_field
from sdhn_base.ros import topics
from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_bringup.launch_config import LAUNCHER_SETS, LaunchConfig
from sdhn_bringup.launch_graph import graph
from sdhn_sim.envs.conditions import ConditionsError, conditions_from_dict
from sdhn_sim.envs.registry import RWARE_TASKS, env_names, team_size
from sdhn_sim.faults import FaultsError, parse_faults
from sdhn_sim.lockstep import CLOCKS

MODES = ("deploy", "train")
RESTART_POLICIES = ("never", "on-failure")
DISCOVERY_MODES = ("simple", "server")


class LaunchConfigError(ConfigError):
    """Invalid launch configuration; the message names the field and the allowed values."""


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
    deaf = cfg.restart.deaf_trainer_s
    if not (isinstance(deaf, int | float) and not isinstance(deaf, bool)
            and 0 <= deaf < float("inf")):
        raise LaunchConfigError(f"restart.deaf_trainer_s: got {deaf!r}; allowed: seconds >= 0 "
                                "(0 = never)")
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
    if cfg.final_approach and not cfg.break_stalls:
        raise LaunchConfigError("final_approach: applies only with break_stalls: true (its hold "
                                "would deadlock corridors without stall breaking)")
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
