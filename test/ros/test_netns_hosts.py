"""Robots on separate hosts, shown with network namespaces: the simulator, each actor and the
observer run on their own "host" (namespace) of a closed test network (``netns.py``), talking UDP
over veths and a bridge, with discovery set as a user sets it on a real network."""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from sdhn_base.drops import DropKind
from sdhn_base.ros import topics
from sdhn_base.ros.status import EventReader
from sdhn_sim.recording.reader import Recording, read_recording

from .deploy_helpers import (
    EXACT_DEADLINE_S,
    actor_cmd,
    inprocess_greedy_actions,
    sim_cmd,
    stop_all,
)
from .netns import Net, closed_network, host_env, netem_unavailable_reason, unavailable_reason
from .processes import REPO, ROS2, node_processes

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
            actor_cmd(i, N, ns, weights_file=weights, greedy=True, action_readers=2), env)
            for i in range(N)]  # action readers: the simulator and the observer
        with node_processes(_observer_cmd(net, env, ns, out, episodes), *actors) as procs:
            obs = procs[0]
            assert obs.wait_for_line("observer: actors seen", 90), obs.output
            with node_processes(net.hosts["sim"].exec(
                    sim_cmd(ns=ns, seed=seed, episodes=episodes, max_steps=max_steps,
                            extra_subscribers=1, step_deadline=EXACT_DEADLINE_S),
                    env)) as (sim,):
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


FAULT_HOSTS = ["sim", "trainer", "recorder", *[f"actor{i}" for i in range(N)]]
# the trainer's step-level drops
STEPPED = (DropKind.MISSED_ACTION, DropKind.INCOMPLETE_STEP, DropKind.STEP_NEVER_SEEN)
# Netem profiles of issue 18, on both ends of every actor's cable for the whole run.
NETEM = {"delay-5ms": ["delay", "5ms"], "jitter-20ms-10ms": ["delay", "20ms", "10ms"],
         "loss-5pct": ["loss", "5%"]}


@dataclass
class FaultRun:
    """What a train-mode run across namespaces left: the simulator's events, the trainer's
    last status, the recording, each node's output, and when the fault began and ended."""

    events: list[dict[str, Any]]
    trainer: dict[str, Any]
    recording: Recording
    outputs: dict[str, str]
    alive: dict[str, bool]
    t_down: float = 0.0
    t_up: float = 0.0

    @property
    def stopped(self) -> dict[str, Any]:
        ends = [e for e in self.events if e["event"] == "stopped"]
        assert len(ends) == 1, (self.events[-3:], self.outputs["sim"])
        return ends[0]


def _fault_run(weights: Path, tmp_path: Path, ns: str, fault: Callable[[Net], None], *,
               after_s: float, deadline: float = 0.5) -> FaultRun:
    """The train-mode graph with the simulator, the trainer, the recorder and each actor on its
    own host; ``fault(net)`` runs once the team is stepping (past the start handshake and the
    first episode), the simulator is stopped ``after_s`` later, then the trainer (once it took
    the last messages), the recorder and the actors. Every node must stop with exit 0."""
    status, events, mcap = tmp_path / "status", tmp_path / "sim-events.jsonl", tmp_path / "r.mcap"
    config = tmp_path / "trainer.yaml"
    config.write_text("ppo:\n  epochs: 1\nlog:\n  tensorboard: false\n")
    with closed_network(FAULT_HOSTS) as net:
        def on(host: str, name: str, args: list[str]) -> list[str]:
            env = {**host_env(net), "SDHN_READY_FILE": str(status / f"{name}.ready")}
            return net.hosts[host].exec(args, env)

        trainer = on("trainer", "trainer", [
            *ROS2, "run", "sdhn_train", "trainer", "--ros-args", "-r", f"__ns:={ns}",
            "-p", "env:=maif-tiny", "-p", f"team_ns:={ns}", "-p", f"run_dir:={tmp_path / 'run'}",
            "-p", "rollout_steps:=256", "-p", f"config:={config}"])
        recorder = on("recorder", "recorder", [
            *ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-r", f"__ns:={ns}",
            "-p", f"team_ns:={ns}", "-p", f"output:={mcap}", "-p", "viz:=false"])
        # action readers: the simulator, the trainer and the recorder
        actors = [on(f"actor{i}", f"actor_{i}", actor_cmd(i, N, ns, seed=i, action_readers=3))
                  for i in range(N)]
        with node_processes(trainer, recorder, *actors) as procs:
            for p in procs:
                assert p.wait_for_line("ready", 90), p.output
            with node_processes(on("sim", "sim", sim_cmd(
                    ns=ns, seed=3, episodes=0, max_steps=60, step_deadline=deadline,
                    extra_subscribers=2, events_file=str(events)))) as (sim,):
                reader = EventReader(events)
                seen: list[dict[str, Any]] = []
                end = time.monotonic() + 90
                while not any(e["event"] == "episode" for e in seen):
                    assert time.monotonic() < end and sim.proc.poll() is None, sim.output
                    seen += reader.new()
                    time.sleep(0.05)
                time.sleep(1.0)
                t0 = time.time()
                fault(net)
                t1 = time.time()
                time.sleep(after_s)
                names = ["sim", "trainer", "recorder", *[f"actor_{i}" for i in range(N)]]
                alive = {n: p.proc.poll() is None for n, p in zip(names, [sim, *procs],
                                                                    strict=True)}
                stop_all([sim])
            time.sleep(2.0)  # the trainer and the recorder take the last step's messages
            stop_all(procs[:1])  # the trainer settles every pending step and writes its status
            stop_all(procs[1:2])
            stop_all(procs[2:])
    return FaultRun(events=seen + reader.new(),
                    trainer=json.loads((status / "trainer.status.json").read_text()),
                    recording=read_recording(mcap),
                    outputs={n: p.output for n, p in zip(names, [sim, *procs], strict=True)},
                    alive=alive, t_down=t0, t_up=t1)


def _assert_kept(run: FaultRun) -> tuple[int, int, list[Any]]:
    """No node crashed; the recording holds every step the simulator made; the trainer turned
    every one into a transition or a counted step drop. Returns (steps, missed, states)."""
    assert all(run.alive.values()), (run.alive, run.outputs)
    for name, out in run.outputs.items():
        assert "Traceback" not in out, f"{name}:\n{out}"
    steps, missed = int(run.stopped["steps"]), int(run.stopped["missed"])
    rec = run.recording
    assert rec.truncated is None, rec.truncated.line()
    # (a) the recording: a TeamState and every robot's observation for each step the sim made
    states = sorted((m.log_time_ns, s) for m, s in rec.decoded(f"/{topics.STATE}",
                                                             "sdhn_msgs/msg/TeamState"))
    keys = [(int(s.episode), int(s.step)) for _, s in states]
    assert len(set(keys)) == len(keys), "a state recorded twice"
    by_ep: dict[int, list[int]] = {}
    for e, t in keys:
        by_ep.setdefault(e, []).append(t)
    assert sorted(by_ep) == list(range(len(by_ep))), f"episodes recorded: {sorted(by_ep)}"
    for e, ts in by_ep.items():
        assert sorted(ts) == list(range(max(ts) + 1)), f"episode {e}: steps {sorted(ts)}"
    # every state after an episode's step 0 is one step the simulator made (one advance)
    assert sum(max(ts) for ts in by_ep.values()) == steps, (steps, {e: max(ts) for e, ts in
                                                                    by_ep.items()})
    assert sum(int(s.missed_actions) for _, s in states) == missed
    for i in range(N):
        obs = {(int(o.episode), int(o.step)) for _, o in rec.decoded(
            f"/{topics.robot_obs(i)}", "sdhn_msgs/msg/RobotObservation")}
        assert obs == set(keys), f"robot {i}: {len(set(keys) - obs)} observations not recorded"
    ended = [e for e in run.events if e["event"] == "episode"]
    assert [int(e["length"]) for e in ended] == [max(by_ep[int(e["episode"])]) for e in ended]
    # (b) the trainer: each step is a transition or a step drop counted with its cause; the
    # simulator's last published step (cut by the stop, never stepped) is the one more
    st = run.trainer
    drops = st["dropped"]
    stayed = sum(1 for _, s in states if s.missed_actions)  # steps the sim took with a 'stay'
    assert st["pending"] == 0, st
    assert st["transitions"] + sum(drops.get(k, 0) for k in STEPPED) == steps + 1, st
    assert drops.get(DropKind.MISSED_ACTION, 0) == stayed, (drops, stayed)
    assert st["transitions"] == steps - stayed, (st, steps, stayed)
    assert set(drops) <= {*STEPPED, DropKind.STALE_STEP}, drops
    return steps, missed, states


def _load() -> str:
    return "load " + "/".join(f"{x:.2f}" for x in os.getloadavg())


def test_link_down_3s_then_up(weights: Path, tmp_path: Path) -> None:
    """Train mode, one actor's cable pulled for 3 s: late actions become `stay` and are counted;
    no node crashes; the recording holds every step the simulator made; the trainer keeps every
    step that arrived complete, and only steps of the actor's outage are missing; the actor acts
    again within 2 s of the link coming back."""
    victim = 2

    def pull(net: Net) -> None:
        net.link(f"actor{victim}", up=False)
        time.sleep(3.0)
        net.link(f"actor{victim}", up=True)

    run = _fault_run(weights, tmp_path, "/sdhn_linkdown", pull, after_s=5.0)
    steps, missed, states = _assert_kept(run)
    assert missed >= 1, run.outputs["sim"]
    # Only the victim, and only in its outage (it may need a step or two to come back): each
    # stayed step lacks one action, and came between the cable pulled and 2 s after it is back.
    outage = [(t / 1e9, int(s.missed_actions)) for t, s in states if s.missed_actions]
    assert all(n == 1 for _, n in outage), outage
    assert all(run.t_down < t < run.t_up + 2.0 for t, _ in outage), (
        [round(t - run.t_down, 2) for t, _ in outage], run.t_up - run.t_down)
    # Acting again: the first action of the victim the simulator used after the link came back
    # (its step's successor state has no missed action), at its arrival on the recorder's host.
    used = {(int(s.episode), int(s.step) - 1) for _, s in states
            if s.step > 0 and not s.missed_actions}
    after = [(m.log_time_ns / 1e9, (int(a.episode), int(a.step))) for m, a in
             run.recording.decoded(f"/{topics.robot_action(victim)}", "sdhn_msgs/msg/RobotAction")
             if m.log_time_ns / 1e9 >= run.t_up]
    mine = sorted(t for t, key in after if key in used)
    assert mine, f"robot {victim} never acted again after the link came back"
    back = mine[0] - run.t_up
    heard = min(t for t, _ in after) - run.t_up  # its first action of any step, stale or not
    span = (states[-1][0] - states[0][0]) / 1e9
    print(f"\n[netns link-down, train mode] steps={steps} missed={missed} (stayed steps "
          f"{len(outage)}) transitions={run.trainer['transitions']} drops="
          f"{run.trainer['dropped']}; first action heard {heard:.2f} s, acting again (an action "
          f"the sim used) {back:.2f} s after the link came back; "
          f"{steps / span:.0f} steps/s over the run; {_load()}")
    assert back < 2.0, f"robot {victim} acted again {back:.2f} s after the link came back"


@pytest.mark.skipif(netem_unavailable_reason() is not None,
                    reason=f"{netem_unavailable_reason()}")
@pytest.mark.parametrize("profile", NETEM)
def test_netem_profile(weights: Path, tmp_path: Path, profile: str) -> None:
    """Issue 18's netem profiles on every actor's cable for a whole train-mode run: late actions
    become `stay` and are counted, no node crashes, the recording holds every step and the
    trainer accounts for each (skipped, with the kernel's answer, where netem does not exist)."""
    def shape(net: Net) -> None:
        for i in range(N):
            net.netem(f"actor{i}", NETEM[profile])

    run = _fault_run(weights, tmp_path, f"/sdhn_netem_{profile.replace('-', '_')}", shape,
                     after_s=5.0)
    steps, missed, _ = _assert_kept(run)
    print(f"\n[netns netem {profile}] steps={steps} missed={missed} "
          f"transitions={run.trainer['transitions']} drops={run.trainer['dropped']}; {_load()}")


def test_launcher_hosts_runs_the_graph_across_namespaces(weights: Path, tmp_path: Path) -> None:
    """``hosts:`` in the launch config puts the simulator, the recorder and each actor on its own
    host; the run completes its episodes and the recording is written."""
    with closed_network(["sim", "recorder", *[f"actor{i}" for i in range(N)]]) as net:
        sets = [f"hosts.{name}={h.netns}" for name, h in net.hosts.items()
                if name in ("sim", "recorder")]
        sets += [f"hosts.actor_{i}={net.hosts[f'actor{i}'].netns}" for i in range(N)]
        args = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml",
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
