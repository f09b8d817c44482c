"""What a launch configuration is: the fields of one launch file (:class:`LaunchConfig`, read and
checked by :mod:`sdhn_bringup.launch_load`) and what follows from them alone (how the actors choose
their actions, whether the recorder is its own node, where the recording goes).

The fields, their defaults and meanings are listed in :mod:`sdhn_bringup.supervisor`'s help
(``python -m sdhn_bringup --help``) and in docs/running-the-stack.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class RestartConfig:
    policy: str = "never"  # never | on-failure
    max_restarts: int = 3  # per child
    # train mode: a trainer that hears nothing this long while the simulator plays is killed
    # for a fresh process under on-failure (sdhn_bringup.trainer_watch); 0 = never
    deaf_trainer_s: float = 60.0


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
    final_approach: bool = False  # with break_stalls, MAIF: the actors' final_approach
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
        approach = " and the final approach" if cfg.final_approach else ""
        return f"greedy, with stall breaking (rule {rule}){approach}{reckon}"
    return "greedy" + reckon


def recorder_node(cfg: LaunchConfig) -> bool:
    """Whether the run has the recorder node (else no recording, or the simulator records)."""
    return cfg.recorder and cfg.recorder_where == "node"


def recording_path(cfg: LaunchConfig, run: Path) -> Path:
    """Where the recorder writes: a bare file, or a bag directory (recorder_node's rule: an
    output not ending in .mcap is a rosbag2 bag directory)."""
    return run / ("recording" if cfg.recorder_format == "bag" else "recording.mcap")
