"""Robots on separate hosts, shown with network namespaces: the simulator, each actor and the
observer run on their own "host" (namespace) of a closed test network (``netns.py``), talking UDP
over veths and a bridge, with discovery set as a user sets it on a real network."""

from __future__ import annotations

import json
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from .deploy_helpers import actor_cmd, inprocess_greedy_actions, sim_cmd, stop_all
from .netns import Net, closed_network, host_env, unavailable_reason
from .processes import REPO, node_processes

pytestmark = pytest.mark.skipif(unavailable_reason() is not None,
                                reason=f"network namespaces unavailable: {unavailable_reason()}")

N = 4
HOSTS = ["sim", *[f"actor{i}" for i in range(N)], "observer"]


def _observer_cmd(net: Net, env: dict[str, str], ns: str, out: Path, episodes: int, *,
                  stop_file: Path | None = None, timeout: float = 120.0) -> list[str]:
    env = {**env, "PYTHONPATH": f"{REPO / 'test'}:{os.environ.get('PYTHONPATH', '')}"}
    args = [sys.executable, "-m", "ros.netns_observer", "--robots", str(N), "--ns", ns,
            "--episodes", str(episodes), "--out", str(out), "--timeout", str(timeout)]
    if stop_file is not None:
        args += ["--stop-file", str(stop_file)]
    return net.hosts["observer"].exec(args, env)


def _rate(actions: list[list[Any]]) -> tuple[float, float]:
    """(team steps/s, mean ms per step) from the observer's arrival times of complete steps."""
    last: dict[tuple[int, int], float] = {}
    for e, s, _r, _a, t in actions:
        last[(e, s)] = max(last.get((e, s), 0.0), t)
    times = sorted(last.values())
    if len(times) < 2:
        return 0.0, float("nan")
    span = times[-1] - times[0]
    return (len(times) - 1) / span, 1000 * span / (len(times) - 1)


@pytest.mark.parametrize("discovery", ["multicast", "static_peers"])
def test_deploy_across_namespaces_equals_inprocess_greedy_rollout(
        weights: Path, tmp_path: Path, discovery: str) -> None:
    seed, episodes, max_steps = 5, 2, 40
    expected = inprocess_greedy_actions(weights, "maif-tiny", seed, episodes, max_steps)
    ns = "/sdhn_hosts"
    with closed_network(HOSTS, multicast=discovery == "multicast") as net:
        env = host_env(net, static_peers=discovery == "static_peers")
        out = tmp_path / "seen.json"
        actors = [net.hosts[f"actor{i}"].exec(
            actor_cmd(i, N, ns, weights_file=weights, greedy=True), env) for i in range(N)]
        with node_processes(_observer_cmd(net, env, ns, out, episodes), *actors) as procs:
            obs = procs[0]
            assert obs.wait_for_line("observer: actors seen", 90), obs.output
            with node_processes(net.hosts["sim"].exec(
                    sim_cmd(ns=ns, seed=seed, episodes=episodes, max_steps=max_steps,
                            extra_subscribers=1), env)) as (sim,):
                assert sim.proc.wait(timeout=120) == 0, sim.output
            assert obs.proc.wait(timeout=30) == 0, obs.output
            stop_all(procs[1:])
    seen = json.loads(out.read_text())
    assert seen["complete"], (obs.output, sim.output)
    assert all(ep["missed_actions"] == 0 for ep in seen["episodes"]), sim.output
    table: dict[tuple[int, int], dict[int, int]] = {}
    for e, s, r, a, _t in seen["actions"]:
        table.setdefault((e, s), {})[r] = a
    for e in range(episodes):
        got = [[table[(e, s)][r] for r in range(N)] for s in sorted(s for (ee, s) in table
                                                                    if ee == e)]
        assert len(got) == len(expected[e]) == seen["episodes"][e]["length"]
        for t, (a, b) in enumerate(zip(got, expected[e], strict=True)):
            assert a == b, f"episode {e} step {t}: ROS actions {a}, in-process {b}"
    rate, ms = _rate(seen["actions"])
    print(f"\n[netns {discovery}] {rate:.1f} team steps/s, {ms:.1f} ms/step, "
          f"load {os.getloadavg()[0]:.2f}")


def test_link_down_3s_then_up(weights: Path, tmp_path: Path) -> None:
    """One actor's cable pulled for 3 s: its late actions become `stay` and are counted, nothing
    crashes, and it acts again within 2 s of the link coming back."""
    ns, victim, deadline = "/sdhn_linkdown", 2, 0.5
    with closed_network(HOSTS) as net:
        env = host_env(net)
        out, stop = tmp_path / "seen.json", tmp_path / "stop"
        actors = [net.hosts[f"actor{i}"].exec(
            actor_cmd(i, N, ns, weights_file=weights, greedy=True), env) for i in range(N)]
        with node_processes(_observer_cmd(net, env, ns, out, 10**6, stop_file=stop,
                                          timeout=300), *actors) as procs:
            obs = procs[0]
            assert obs.wait_for_line("observer: actors seen", 90), obs.output
            with node_processes(net.hosts["sim"].exec(
                    sim_cmd(ns=ns, seed=3, episodes=0, max_steps=60, step_deadline=deadline,
                            extra_subscribers=1), env)) as (sim,):
                # Pull the cable only once the team is stepping (past the start handshake).
                assert sim.wait_for_line("return=", 60), sim.output
                time.sleep(2.0)
                net.link(f"actor{victim}", up=False)
                t_down = time.time()
                time.sleep(3.0)
                net.link(f"actor{victim}", up=True)
                t_up = time.time()
                time.sleep(5.0)
                alive = [p.proc.poll() is None for p in [sim, *procs]]
                stop_all([sim])
            stop.touch()
            assert obs.proc.wait(timeout=30) == 0, obs.output
            stop_all(procs[1:])
    assert all(alive), [p.output for p in [sim, *procs]]
    m = re.search(r"totals: (\d+) steps, (\d+) missed actions", sim.output)
    assert m is not None, sim.output
    steps, missed = int(m.group(1)), int(m.group(2))
    seen = json.loads(out.read_text())
    mine = sorted(t for _e, _s, r, _a, t in seen["actions"] if r == victim)
    during = [t for t in mine if t_down + 0.2 < t < t_up]
    after = [t for t in mine if t >= t_up]
    assert not during, f"robot {victim} acted while its link was down"
    assert missed >= 1, sim.output
    assert after, f"robot {victim} never acted after the link came back"
    back = after[0] - t_up
    rate, ms = _rate(seen["actions"])
    print(f"\n[netns link-down] steps={steps} missed={missed} back after {back:.2f} s; "
          f"{rate:.1f} team steps/s, {ms:.1f} ms/step, load {os.getloadavg()[0]:.2f}")
    assert back < 2.0, f"robot {victim} acted again {back:.2f} s after the link came back"


def test_launcher_hosts_runs_the_graph_across_namespaces(weights: Path, tmp_path: Path) -> None:
    """``hosts:`` in the launch config puts the simulator, the recorder and each actor on its own
    host; the run completes its episodes and the recording is written."""
    with closed_network(["sim", "recorder", *[f"actor{i}" for i in range(N)]]) as net:
        sets = [f"hosts.{name}={h.netns}" for name, h in net.hosts.items()
                if name in ("sim", "recorder")]
        sets += [f"hosts.actor_{i}={net.hosts[f'actor{i}'].netns}" for i in range(N)]
        args = [sys.executable, "-m", "sdhn_sim.launch", "configs/launch/deploy-tiny.yaml",
                "--set", f"weights={weights}", "--set", "episodes=2", "--set",
                f"run_dir={tmp_path / 'run'}", "--set", "team_ns=/sdhn_launch_hosts"]
        for s in sets:
            args += ["--set", s]
        with node_processes(args) as (launcher,):
            code = launcher.proc.wait(timeout=180)
    assert code == 0, launcher.output
    rows = (tmp_path / "run" / "episodes.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 2, launcher.output
    assert (tmp_path / "run" / "recording.mcap").stat().st_size > 0
