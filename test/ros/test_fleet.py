"""Fleets: the launcher with Fast DDS's discovery server (a supervised child; the graph is its
clients only), the opt-in actor host (several robots' nodes in one process, the same actions as
one process per robot), staged start-up, and one scale test with 40 actor processes."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sdhn_bringup.launch_config import LaunchConfig
from sdhn_bringup.launch_graph import DISCOVERY_CHILD, graph
from sdhn_bringup.launch_load import LaunchConfigError, load_config, validate
from sdhn_bringup.supervisor import start_stages

from .processes import node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]

TOPICS_SCRIPT = """
import sys, time, rclpy
rclpy.init()
node = rclpy.create_node("probe")
end = time.monotonic() + float(sys.argv[1])
names = set()
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
    names |= {n for n, _ in node.get_topic_names_and_types()}
print(" ".join(sorted(names)))
"""


def topics_seen(seconds: float, **env: str) -> set[str]:
    """Topic names a fresh participant finds within ``seconds``, in an environment with
    ``env`` added (a key with value "" is removed)."""
    full = {**os.environ, **env}
    full = {k: v for k, v in full.items() if v}
    done = subprocess.run([sys.executable, "-c", TOPICS_SCRIPT, str(seconds)], env=full,
                          capture_output=True, text=True, timeout=60 + seconds, check=True)
    return set(done.stdout.split())


def rows(run_dir: Path) -> list[dict[str, str]]:
    return list(csv.DictReader((run_dir / "episodes.csv").read_text().splitlines()))


def test_discovery_server_runs_the_graph_and_only_its_clients_see_it(weights: Path,
                                                                     tmp_path: Path) -> None:
    ns = "/sdhn_ds"
    with node_processes([*LAUNCH, "--set", f"weights={weights}", "--set", f"run_dir={tmp_path}",
                         "--set", "discovery=server", "--set", f"team_ns={ns}",
                         "--set", "episodes=0", "--set", "max_steps=20"]) as (launcher,):
        assert launcher.wait_for_line("episode 0:", timeout=120), launcher.output
        port = int(next(line for line in (tmp_path / "launch.yaml").read_text().splitlines()
                        if line.startswith("discovery_port:")).split(":")[1])
        assert port > 0, "a free port was chosen and recorded"
        client = topics_seen(3.0, ROS_DISCOVERY_SERVER=f"127.0.0.1:{port}",
                             ROS_SUPER_CLIENT="TRUE")
        simple = topics_seen(3.0, ROS_DISCOVERY_SERVER="", ROS_SUPER_CLIENT="")
        launcher.proc.send_signal(signal.SIGTERM)
        launcher.proc.wait(timeout=60)
    assert f"{ns}/robot_0/obs" in client, sorted(client)
    assert not {t for t in simple if t.startswith(ns)}, f"simple discovery saw {sorted(simple)}"
    assert launcher.proc.returncode == 0, launcher.output
    assert "discovery=exit 0" in launcher.output, launcher.output
    # the server started (and was ready) before anything else
    pid_lines = [line for line in launcher.lines if "pids:" in line]
    assert pid_lines[0].split("pids: ")[1].startswith(f"{DISCOVERY_CHILD}="), pid_lines
    recorded = rows(tmp_path)
    assert recorded and all(r["missed_actions"] == "0" for r in recorded), recorded
    assert (tmp_path / "recording.mcap").stat().st_size > 0


def test_actor_host_gives_the_same_episodes_as_one_process_per_robot(weights: Path,
                                                                      tmp_path: Path) -> None:
    """Greedy play on the same instances: two hosts of two robots each play exactly the episodes
    four actor processes play (same actor core; decisions do not depend on the process)."""
    results = {}
    for hosts in (0, 2):
        run = tmp_path / f"hosts{hosts}"
        with node_processes([*LAUNCH, "--set", f"weights={weights}", "--set", f"run_dir={run}",
                             "--set", f"actor_hosts={hosts}", "--set", "episodes=2",
                             "--set", "recorder=false", "--set", "max_steps=40",
                             "--set", f"team_ns=/sdhn_host{hosts}"]) as (launcher,):
            launcher.proc.wait(timeout=120)
        assert launcher.proc.returncode == 0, launcher.output
        results[hosts] = [{k: r[k] for k in ("instance_id", "completed", "makespan", "return",
                                             "length", "missed_actions")} for r in rows(run)]
    logs = sorted(p.name for p in (tmp_path / "hosts2" / "logs").iterdir())
    assert logs == ["actor_host_0.log", "actor_host_1.log", "sim.log"], logs
    assert results[0] == results[2], results
    assert all(r["missed_actions"] == "0" for r in results[2])


def test_fleet_options_are_validated_and_staged(weights: Path) -> None:
    base = LaunchConfig(env="maif-tiny", weights=str(weights))
    for field, value, word in (("discovery", "zeroconf", "discovery"),
                               ("discovery_port", 70000, "discovery_port"),
                               ("actor_hosts", 5, "actor_hosts"),
                               ("start_batch", -1, "start_batch")):
        cfg = LaunchConfig(**{**base.__dict__, field: value})
        with pytest.raises(LaunchConfigError, match=word):
            validate(cfg)
    with pytest.raises(LaunchConfigError, match="managed"):
        validate(LaunchConfig(**{**base.__dict__, "actor_hosts": 2, "managed": True}))
    cfg = load_config(None, [f"weights={weights}", "discovery=server", "start_batch=3",
                             "env=maif-10", "run_dir=/tmp/x"])
    assert cfg.discovery_port > 0
    children = graph(cfg)
    assert children[0].name == DISCOVERY_CHILD and children[0].ready_line
    assert children[0].env["ROS_DISCOVERY_SERVER"] == ""  # the server is no client of itself
    recorder = next(c for c in children if c.name == "recorder")
    assert recorder.env == {"ROS_SUPER_CLIENT": "TRUE"}

    class Stub:  # start_stages reads only the spec
        def __init__(self, spec: object) -> None:
            self.spec = spec

    stages = start_stages([Stub(c) for c in children], 3)  # type: ignore[arg-type]
    names = [[c.spec.name for c in s] for s in stages]
    assert names[0] == [DISCOVERY_CHILD] and names[1] == ["recorder", "sim"]
    assert names[2:] == [[f"actor_{i}" for i in range(k, min(k + 3, 10))]
                         for k in range(0, 10, 3)]


def test_forty_actor_processes_play_lock_step(weights: Path, tmp_path: Path) -> None:
    """The scale test: maif-40 with one actor process per robot, started in batches, plays a
    few lock-step steps with no missed action (the 100-robot figures: scripts/bench_fleet.py)."""
    with node_processes([*LAUNCH, "--set", f"weights={weights}", "--set", f"run_dir={tmp_path}",
                         "--set", "env=maif-40", "--set", "episodes=1", "--set", "max_steps=5",
                         "--set", "recorder=false", "--set", "start_batch=20",
                         "--set", "start_timeout=300", "--set", "step_deadline=5",
                         "--set", "stop_timeout=30",
                         "--set", "team_ns=/sdhn_forty"]) as (launcher,):
        launcher.proc.wait(timeout=600)
    assert launcher.proc.returncode == 0, launcher.output[-3000:]
    assert "41/41 ready" in launcher.output, launcher.output[-3000:]
    (row,) = rows(tmp_path)
    assert row["length"] == "5" and row["missed_actions"] == "0", row
