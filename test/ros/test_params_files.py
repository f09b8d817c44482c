"""ROS parameters files (``--ros-args --params-file``): every shipped file under configs/params
starts its node with exactly its values (asked back through the node's parameter service), a
wrong type or an out-of-range value in a file is one line and exit 2, the launcher writes one file
per run that gives every node its parameters, and docs/parameters.md lists what the nodes
declare."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from rcl_interfaces.srv import GetParameters
from rclpy.context import Context
from rclpy.parameter import parameter_value_to_python

from sdhn_bringup.launch_graph import PARAMS_FILE, graph, node_parameters
from sdhn_bringup.launch_load import load_config
from sdhn_bringup.params_doc import main as params_doc

from .own_node import own_node_and_executor
from .processes import REPO, ROS2, node_processes

PARAMS = REPO / "configs" / "params"
ATTEMPT_S = 5.0  # how long one get_parameters request may go unanswered
# file -> (package, executable, namespace, node full name, overrides the test needs)
NODES: dict[str, tuple[str, str, str, str, dict[str, Any]]] = {
    "sim.yaml": ("sdhn_sim", "sim", "/sdhn", "/sdhn/sim", {}),
    "actor.yaml": ("sdhn_policy", "actor", "/sdhn/robot_2", "/sdhn/robot_2/actor", {}),
    "trainer.yaml": ("sdhn_train", "trainer", "/sdhn", "/sdhn/trainer", {"run_dir": "{tmp}/t"}),
    "recorder.yaml": ("sdhn_sim", "recorder", "/sdhn", "/sdhn/recorder",
                      {"output": "{tmp}/r.mcap"}),
    "viz.yaml": ("sdhn_sim", "viz", "/", "/viz", {"port": 0}),
}


def file_values(path: Path, fqn: str) -> dict[str, Any]:
    """What rcl gives node ``fqn`` from ``path``: the '/**' entry, then its own name's."""
    doc = yaml.safe_load(path.read_text())
    values: dict[str, Any] = {}
    for key in ("/**", fqn):
        values.update(doc.get(key, {}).get("ros__parameters", {}))
    return values


def ask(fqn: str, names: list[str], timeout: float = 30.0) -> dict[str, Any]:
    """The node's current values of ``names``, through its get_parameters service."""
    with own_node_and_executor("params_file_test") as (node, executor):
        client = node.create_client(GetParameters, f"{fqn}/get_parameters")
        assert client.wait_for_service(timeout_sec=timeout), f"{fqn}: no parameter service"
        # A service can answer before its response writer has matched this client's response
        # reader; rmw_fastrtps then drops the response after waiting 100 ms (ros2/rmw_fastrtps
        # #467), which a busy machine exceeds (seen once in a full run). The request is a read,
        # so ask again instead of waiting for an answer that will never come.
        deadline = time.monotonic() + timeout
        result, attempts = None, 0
        while result is None and time.monotonic() < deadline:
            attempts += 1
            future = client.call_async(GetParameters.Request(names=names))
            executor.spin_until_future_complete(
                future, timeout_sec=min(ATTEMPT_S, max(deadline - time.monotonic(), 0.1)))
            result = future.result() if future.done() else None
            if result is None:
                client.remove_pending_request(future)
        assert result is not None, f"{fqn}: get_parameters unanswered ({attempts} attempts)"
        return {n: parameter_value_to_python(v) for n, v in zip(names, result.values,
                                                               strict=True)}


@pytest.mark.parametrize("name", sorted(NODES))
def test_shipped_params_file_starts_its_node_with_its_values(name: str, tmp_path: Path) -> None:
    package, executable, ns, fqn, overrides = NODES[name]
    want = file_values(PARAMS / name, fqn)
    assert want, f"{name} gives {fqn} no parameters"
    args = [*ROS2, "run", package, executable, "--ros-args", "-r", f"__ns:={ns}",
            "--params-file", str(PARAMS / name)]
    if overrides:  # paths and ports of this test: a later file wins for the same node name
        extra = tmp_path / "overrides.yaml"
        extra.write_text(yaml.safe_dump({fqn: {"ros__parameters": {
            k: v.format(tmp=tmp_path) if isinstance(v, str) else v
            for k, v in overrides.items()}}}))
        args += ["--params-file", str(extra)]
    with node_processes(args) as (proc,):
        got = ask(fqn, list(want))
        assert proc.proc.poll() is None, proc.output
        proc.stop(timeout=15)
    for key, value in want.items():
        expected = value if key not in overrides else got[key]
        assert got[key] == expected and type(got[key]) is type(expected), \
            f"{name}: {fqn} has {key}={got[key]!r}, the file says {value!r}"
    for key, value in overrides.items():
        assert got[key] == (value.format(tmp=tmp_path) if isinstance(value, str) else value), \
            (key, got[key])


@pytest.mark.parametrize("text,field", [
    ("seed: zero", "seed:"),  # a string where an integer is declared
    ("step_deadline: 0.0", "step_deadline:"),  # below the range 0.001 .. 3600
    ("episodes: -1", "episodes:"),  # below the range >= 0
    ('conditions: "{latency: -1}"', "conditions.latency:"),  # a bad deployment condition
])
def test_bad_value_in_a_params_file_is_one_line_and_exit_2(text: str, field: str,
                                                          tmp_path: Path) -> None:
    params = tmp_path / "sim.yaml"
    params.write_text(f"/**:\n  ros__parameters:\n    env: maif-tiny\n    {text}\n")
    done = subprocess.run([*ROS2, "run", "sdhn_sim", "sim", "--ros-args", "--params-file",
                           str(params)], capture_output=True, text=True, timeout=90,
                          check=False, cwd=REPO)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and field in lines[0] and "allowed" in lines[0], done.stderr


def test_launcher_passes_one_params_file_with_every_nodes_parameters(tmp_path: Path) -> None:
    cfg = load_config(None, ["mode=train", "env=maif-tiny", f"run_dir={tmp_path}",
                             "trainer.algo=mappo", "trainer.some_new_knob=3", "episodes=2"])
    nodes = node_parameters(cfg)
    children = graph(cfg)
    for child in children:
        assert "-p" not in child.command(restart=True), child.ros_args
        i = child.ros_args.index("--params-file")
        assert child.ros_args[i + 1] == str(tmp_path.resolve() / PARAMS_FILE)
    assert list(nodes) == ["/sdhn/recorder", "/sdhn/trainer", "/sdhn/sim",
                           *(f"/sdhn/robot_{i}/actor" for i in range(4))]
    assert nodes["/sdhn/trainer"]["algo"] == "mappo"
    assert nodes["/sdhn/trainer"]["some_new_knob"] == 3
    assert nodes["/sdhn/sim"]["episodes"] == 2
    assert [nodes[f"/sdhn/robot_{i}/actor"]["robot_id"] for i in range(4)] == [0, 1, 2, 3]


def test_launcher_params_file_starts_a_node_with_its_values(tmp_path: Path) -> None:
    from sdhn_bringup.launch_graph import params_file_text

    cfg = load_config(None, ["mode=train", "env=maif-tiny", f"run_dir={tmp_path}",
                             "episodes=2", "step_deadline=0.25"])
    (tmp_path / "status").mkdir()
    path = tmp_path / PARAMS_FILE
    path.write_text(params_file_text(node_parameters(cfg)))
    sim = next(c for c in graph(cfg) if c.name == "sim")
    want = node_parameters(cfg)["/sdhn/sim"]
    with node_processes([*ROS2, "run", "sdhn_sim", "sim", "--ros-args", *sim.ros_args]) as (p,):
        got = ask("/sdhn/sim", list(want))
        p.stop(timeout=15)
    assert got == want


def test_parameters_page_lists_what_the_nodes_declare() -> None:
    assert params_doc(["--check", "--doc", str(REPO / "docs" / "parameters.md")]) == 0, \
        "docs/parameters.md is out of date: python -m sdhn_bringup.params_doc"


def test_restarted_trainer_reads_resume_from_the_later_file(tmp_path: Path) -> None:
    """rcl gives params.yaml's /sdhn/trainer entry precedence over any -p value, so a restart
    passes the resume file after it; a later file wins for the same node name."""
    from sdhn_bringup.launch_graph import RESUME_FILE
    from sdhn_bringup.supervisor import Launcher

    cfg = load_config(None, ["mode=train", "env=maif-tiny", f"run_dir={tmp_path}",
                             "trainer.resume=false"])
    Launcher(cfg).write_params()
    trainer = next(c for c in graph(cfg) if c.name == "trainer")
    args = trainer.command(restart=True)
    assert args[-4:] == ["--params-file", str(tmp_path.resolve() / PARAMS_FILE),
                         "--params-file", str(tmp_path.resolve() / RESUME_FILE)], args
    ros_args = args[args.index("--ros-args"):]
    for restart, want in ((False, False), (True, True)):
        context = Context()
        rclpy.init(args=["trainer", *(ros_args if restart else ros_args[:-2])], context=context)
        node = rclpy.create_node("trainer", namespace="/sdhn", context=context)
        try:
            assert node.declare_parameter("resume", False).value is want, ros_args
        finally:
            node.destroy_node()
            rclpy.try_shutdown(context=context)
