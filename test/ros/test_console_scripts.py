"""Every console script of the three packages starts through the ``ros2 run`` shim, logs, and
stops with exit code 0 on SIGINT or SIGTERM within 5 s. Command-line tools answer ``--help``."""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
from importlib import metadata

import pytest

from .processes import ROS2, node_processes

PACKAGES = ("sdhn_sim", "sdhn_policy", "sdhn_train")
_OUT = tempfile.mkdtemp(prefix="sdhn-console-")  # outputs of the recorder and trainer rows
# Executables that are long-running nodes, with the arguments a minimal start needs.
NODES: dict[tuple[str, str], list[str]] = {
    ("sdhn_sim", "sim"): [],
    ("sdhn_sim", "recorder"): ["-p", f"output:={_OUT}/recording.mcap"],
    ("sdhn_sim", "viz"): ["-p", "port:=0"],
    ("sdhn_policy", "actor"): ["-r", "__ns:=/sdhn/robot_3", "-p", "robot_id:=3"],
    # resume: the second start (other signal) continues the first one's run directory
    ("sdhn_train", "trainer"): ["-p", "env:=maif-tiny", "-p", f"run_dir:={_OUT}/trainer",
                                "-p", "resume:=true"],
}
# Executables that are command-line tools rather than nodes.
TOOLS = {("sdhn_sim", "replay"), ("sdhn_policy", "export_onnx"), ("sdhn_train", "train")}


def installed_executables() -> set[tuple[str, str]]:
    found = set()
    for package in PACKAGES:
        for ep in metadata.distribution(package).entry_points:
            if ep.group == "console_scripts":
                found.add((package, ep.name))
    return found


def test_every_executable_is_covered_here() -> None:
    assert installed_executables() == set(NODES) | TOOLS, "add new executables to this test"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("package,executable", sorted(NODES), ids=str)
def test_node_starts_logs_and_stops_cleanly(package: str, executable: str, sig: int) -> None:
    extra = NODES[(package, executable)]
    command = [*ROS2, "run", package, executable, *(["--ros-args", *extra] if extra else [])]
    with node_processes(command) as (node,):
        # A bound on a hang only (the trainer's start took over 20 s at load 20+ on 2 cores).
        assert node.wait_for_line("ready", timeout=90), f"never logged 'ready':\n{node.output}"
        code = node.stop(sig, timeout=5.0)
    assert code == 0, f"exit code {code} after {signal.Signals(sig).name}:\n{node.output}"
    assert "stopped" in node.output


@pytest.mark.parametrize("package,executable", sorted(TOOLS))
def test_tool_answers_help(package: str, executable: str) -> None:
    done = subprocess.run(
        [*ROS2, "run", package, executable, "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "usage" in done.stdout.lower()


def test_shim_rejects_unknown_executable_with_the_known_ones() -> None:
    done = subprocess.run(
        [*ROS2, "run", "sdhn_sim", "no_such_exe"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2
    assert "no executable 'no_such_exe'" in done.stderr and "sim" in done.stderr


def test_shim_lists_executables() -> None:
    done = subprocess.run(
        [*ROS2, "pkg", "executables"], capture_output=True, text=True, timeout=30, check=False
    )
    listed = {tuple(line.split()) for line in done.stdout.splitlines()}
    assert listed == installed_executables()


def test_python_is_the_venv() -> None:
    # Node processes must run under the venv interpreter (its .pth sets the ROS library path).
    assert sys.prefix != sys.base_prefix, "run the tests with the venv's python"
