"""The multi-process launcher: a small deploy graph (sim + 4 actor processes on maif-tiny) runs
its episodes and ends by itself; SIGTERM stops every child with exit code 0; a killed actor is
reported, and restarted under ``restart.policy: on-failure``."""

from __future__ import annotations

import csv
import dataclasses
import os
import re
import signal
import sys
import time
from pathlib import Path

import pytest

from sdhn_bringup.launch_config import LaunchConfig
from sdhn_bringup.launch_graph import graph, node_parameters
from sdhn_bringup.launch_load import LaunchConfigError, load_config, resolve, validate
from sdhn_policy.stall_breaker import StallRule

from .processes import NodeProcess, node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]


def launch(weights: Path, run_dir: Path, *sets: str) -> list[str]:
    args = [*LAUNCH, "--set", f"weights={weights}", "--set", f"run_dir={run_dir}",
            "--set", "recorder=false", "--set", "max_steps=40", "--set", "status_interval=0.5"]
    for item in sets:
        args += ["--set", item]
    return args


def pid_of(launcher: NodeProcess, name: str) -> int:
    for line in launcher.lines:
        m = re.search(rf"\b{name}=(\d+)", line)
        if "pids:" in line and m:
            return int(m.group(1))
    raise AssertionError(f"no pid of {name}:\n{launcher.output}")


def wait_after(proc: NodeProcess, first: str, then: str, timeout: float) -> bool:
    """True once a line containing ``then`` follows a line containing ``first``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lines = list(proc.lines)
        start = next((k for k, line in enumerate(lines) if first in line), None)
        if start is not None and any(then in line for line in lines[start + 1:]):
            return True
        time.sleep(0.1)
    return False


def test_runs_its_episodes_and_ends_cleanly(weights: Path, tmp_path: Path) -> None:
    with node_processes(launch(weights, tmp_path, "episodes=2", "break_stalls=true",
                               "final_approach=true", "team_ns=/sdhn_launch")) as (launcher,):
        launcher.proc.wait(timeout=60)
    assert launcher.proc.returncode == 0, launcher.output
    assert "every child stopped cleanly" in launcher.output
    text = (tmp_path / "episodes.csv").read_text()
    assert text.startswith("episode,completed,makespan,return,"), text  # outcome first
    rows = list(csv.DictReader(text.splitlines()))
    assert [r["episode"] for r in rows] == ["0", "1"]
    assert all(r["missed_actions"] == "0" and r["length"] == "40" for r in rows), rows
    assert all(r["completed"] in ("True", "False") and int(r["instance_id"]) >= 0 for r in rows)
    logs = {p.name for p in (tmp_path / "logs").iterdir()}
    assert logs == {"sim.log", *(f"actor_{i}.log" for i in range(4))}
    # Readiness and results came as data: every child's ready file, the sim's events.
    status = {p.name for p in (tmp_path / "status").iterdir()}
    assert status == {"sim.ready", "sim-events.jsonl", *(f"actor_{i}.ready" for i in range(4))}
    assert "5/5 ready" in launcher.output, launcher.output
    # each actor process runs its own stall breaker (greedy play, break_stalls from the config)
    # and the final approach after it
    for i in range(4):
        log = (tmp_path / "logs" / f"actor_{i}.log").read_text()
        assert "greedy=True" in log and f"break_stalls={StallRule().text()}" in log, log
        assert "final_approach=True" in log, log


@pytest.mark.parametrize("policy", ["on-failure", "never"])
def test_killed_child_is_reported_and_sigterm_stops_all(weights: Path, tmp_path: Path,
                                                        policy: str) -> None:
    with node_processes(launch(weights, tmp_path, "episodes=0", "step_deadline=0.2",
                               f"team_ns=/sdhn_launch_{policy.replace('-', '_')}",
                               f"restart.policy={policy}")) as (launcher,):
        assert launcher.wait_for_line("episode 0:", timeout=40), launcher.output
        os.kill(pid_of(launcher, "actor_2"), signal.SIGKILL)
        assert launcher.wait_for_line("actor_2 (pid", timeout=10), launcher.output
        assert "killed by SIGKILL" in launcher.output
        if policy == "on-failure":
            assert launcher.wait_for_line("restarted actor_2 (1/3)", timeout=10), launcher.output
            # The restarted actor answers again: a later episode has no missed actions.
            assert wait_after(launcher, "restarted actor_2", "missed 0,", timeout=30), (
                launcher.output)
        else:  # the dead robot's actions miss the deadline: 'stay', counted in the summary
            assert wait_after(launcher, "killed by SIGKILL", "missed 40,", timeout=30), (
                launcher.output)
        code = launcher.stop(signal.SIGTERM, timeout=20)
    out = launcher.output
    assert "exit codes:" in out, out
    final = next(line for line in out.splitlines() if "exit codes:" in line)
    if policy == "on-failure":
        assert code == 0, out
        assert final.count("exit 0") == 5, final
        assert "every child stopped cleanly" in out
    else:
        assert code == 1, out
        assert "actor_2=killed by SIGKILL" in final and final.count("exit 0") == 4, final
        assert "failed: actor_2" in out
        # and why, without opening the file: its log's last lines (here the actor's start-up)
        tail = out.split("actor_2: last lines of", 1)[1]
        assert "[sdhn_launch_never.robot_2.actor]" in tail, out


def test_managed_actors_are_driven_to_active_again_after_a_restart(weights: Path,
                                                                   tmp_path: Path) -> None:
    """managed: true: the launcher drives each actor configure -> activate through the
    lifecycle_msgs services; a killed actor is restarted unconfigured and driven again, and acts
    (a later episode has no missed actions)."""
    ns = "/sdhn_launch_managed"
    with node_processes(launch(weights, tmp_path, "episodes=0", "step_deadline=0.2",
                               f"team_ns={ns}", "managed=true",
                               "restart.policy=on-failure")) as (launcher,):
        assert launcher.wait_for_line("episode 0:", timeout=60), launcher.output
        for i in range(4):
            assert f"actor_{i}: {ns}/robot_{i}/actor active" in launcher.output, launcher.output
        os.kill(pid_of(launcher, "actor_2"), signal.SIGKILL)
        assert launcher.wait_for_line("restarted actor_2 (1/3)", timeout=20), launcher.output
        assert wait_after(launcher, "restarted actor_2", f"actor_2: {ns}/robot_2/actor active",
                          timeout=30), launcher.output
        assert wait_after(launcher, f"actor_2: {ns}/robot_2/actor active", "missed 0,",
                          timeout=40), launcher.output
        code = launcher.stop(signal.SIGTERM, timeout=20)
    assert code == 0, launcher.output
    assert "every child stopped cleanly" in launcher.output


def test_bad_config_exits_2_naming_the_field(tmp_path: Path) -> None:
    with node_processes([*LAUNCH, "--set", "mode=fly"]) as (launcher,):
        launcher.proc.wait(timeout=30)
    assert launcher.proc.returncode == 2
    assert "mode:" in launcher.output and "allowed: deploy, train" in launcher.output


def test_managed_is_refused_across_hosts() -> None:
    with pytest.raises(LaunchConfigError, match=r"^managed: .*allowed: false when hosts"):
        load_config(None, ["mode=train", "managed=true", "hosts.sim=somewhere"])
    cfg = resolve(load_config(None, ["mode=train", "managed=true"]))
    managed = graph(cfg)
    assert [c.name for c in managed if c.managed] == [f"actor_{i}" for i in range(4)]
    params = node_parameters(cfg)
    assert all(params[c.node_name]["managed"] is True for c in managed if c.managed)
    assert managed[-1].node_name == "/sdhn/robot_3/actor"


def test_validate_checks_without_changing_and_resolve_fills_in(weights: Path) -> None:
    cfg = LaunchConfig(env="maif-tiny", weights=str(weights.parent))
    before = dataclasses.asdict(cfg)
    validate(cfg)
    assert dataclasses.asdict(cfg) == before, "validate changed what it checked"
    done = resolve(cfg)
    assert dataclasses.asdict(cfg) == before
    assert done.robots == 4 and done.weights.endswith(".safetensors") and done.run_dir


def test_trainer_section_is_passed_through_by_name(tmp_path: Path) -> None:
    cfg = load_config(None, ["mode=train", "env=maif-tiny", f"run_dir={tmp_path}",
                             "trainer.algo=mappo", "trainer.some_new_knob=3"])
    trainer = node_parameters(cfg)["/sdhn/trainer"]  # the trainer's part of the params file
    assert trainer["algo"] == "mappo" and trainer["some_new_knob"] == 3, trainer
    with pytest.raises(LaunchConfigError, match=r"trainer\.seed: set by the launcher"):
        load_config(None, ["mode=train", "trainer.seed=3"])


def test_temperature_reaches_the_actors_only_in_sampled_deployment(weights: Path) -> None:
    base = ["mode=deploy", "env=maif-tiny", f"weights={weights}"]
    cfg = load_config(None, [*base, "greedy=false", "temperature=0.5"])
    params = node_parameters(resolve(cfg))
    assert {params[f"/sdhn/robot_{i}/actor"]["temperature"] for i in range(4)} == {0.5}
    for bad, why in [(["greedy=false", "temperature=0"], "allowed: a number"),
                     (["greedy=false", "temperature=nan"], "allowed: a number"),
                     (["greedy=true", "temperature=0.5"], "only to deploy mode with greedy")]:
        with pytest.raises(LaunchConfigError, match=f"^temperature: .*{why}"):
            load_config(None, [*base, *bad])

def test_break_stalls_reaches_the_actors_only_in_greedy_maif_deployment(weights: Path) -> None:
    base = ["mode=deploy", "env=maif-tiny", f"weights={weights}"]
    params = node_parameters(resolve(load_config(None, [*base, "break_stalls=true"])))
    assert {params[f"/sdhn/robot_{i}/actor"]["break_stalls"] for i in range(4)} == {True}
    params = node_parameters(resolve(load_config(None, base)))
    assert {params[f"/sdhn/robot_{i}/actor"]["break_stalls"] for i in range(4)} == {False}
    rware = Path(__file__).resolve().parents[2] / "models" / "rware-3-mappo"
    for bad, why in [(["break_stalls=true", "greedy=false"], "greedy: true"),
                     (["break_stalls=true", "env=rware-3", f"weights={rware}"], "RWARE")]:
        with pytest.raises(LaunchConfigError, match=f"^break_stalls: .*{why}"):
            load_config(None, [*base, *bad])
    # a chosen rule reaches every actor; without one the actors keep their default
    params = node_parameters(resolve(load_config(None, [*base, "break_stalls=true",
                                                        "stall_rule=2,10,2"])))
    assert {params[f"/sdhn/robot_{i}/actor"]["stall_rule"] for i in range(4)} == {"2,10,2"}
    assert "stall_rule" not in node_parameters(resolve(load_config(
        None, [*base, "break_stalls=true"])))["/sdhn/robot_0/actor"]
    for bad, why in [(["stall_rule=2,10,2"], "only with break_stalls"),
                     (["break_stalls=true", "stall_rule=2,10"], "CALM,PROGRESS")]:
        with pytest.raises(LaunchConfigError, match=f"^stall_rule: .*{why}"):
            load_config(None, [*base, *bad])
    # the final approach: with stall breaking only, and it reaches every actor
    params = node_parameters(resolve(load_config(None, [*base, "break_stalls=true",
                                                        "final_approach=true"])))
    assert {params[f"/sdhn/robot_{i}/actor"]["final_approach"] for i in range(4)} == {True}
    params = node_parameters(resolve(load_config(None, [*base, "break_stalls=true"])))
    assert {params[f"/sdhn/robot_{i}/actor"]["final_approach"] for i in range(4)} == {False}
    with pytest.raises(LaunchConfigError, match=r"^final_approach: .*only with break_stalls"):
        load_config(None, [*base, "final_approach=true"])
    with pytest.raises(LaunchConfigError, match=r"^final_approach: .*only with break_stalls"):
        load_config(None, [*base, "final_approach=true", "greedy=false"])


@pytest.mark.parametrize("ns", ["sdhn", "/sdhn/", "/1team", "/a__b", ""])
def test_team_ns_follows_the_one_rule(ns: str) -> None:
    with pytest.raises(LaunchConfigError, match="team_ns"):
        load_config(None, ["mode=train", f"team_ns={ns}"])
