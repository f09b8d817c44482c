"""The graph one launch configuration starts: every node's parameters and the run's parameters
file, and the children in start order (:func:`graph`: recorder, trainer, simulator, the actors or
actor hosts, the Fast DDS discovery server first when ``discovery: server``), each a
:class:`ChildSpec` that knows its command line. Nothing here starts a process:
:mod:`sdhn_bringup.supervisor` does.
"""

from __future__ import annotations

import itertools
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sdhn_base.ros import topics
from sdhn_bringup.launch_config import LaunchConfig, recorder_node, recording_path
from sdhn_sim.faults import faults_text, parse_faults

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
            "final_approach": bool(cfg.final_approach and cfg.break_stalls
                                   and cfg.mode == "deploy"),
            "env": cfg.env, "managed": cfg.managed, "realtime": cfg.clock == "realtime",
            "dead_reckoning": bool(cfg.dead_reckoning and cfg.mode == "deploy"),
            # the readers of its actions the simulator waits for before step 0: itself and the
            # extra subscribers (the actor holds its obs subscription until its writer has
            # matched them all; sdhn_policy.actor_node)
            "action_readers": 1 + extra}
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
