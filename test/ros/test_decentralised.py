"""Decentralised execution with real processes: 4 robots on maif-tiny, each actor its own OS
process that subscribes only to its own observation topic (and the weights topic); an episode
completes in lock-step and every robot's action of every step arrives."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.node import NodeNameNonExistentError

from .deploy_helpers import EXACT_DEADLINE_S, actor_cmd, observer, sim_cmd, stop_all
from .processes import node_processes

N = 4
STEPS = 30


def test_each_actor_process_sees_only_its_own_observation(weights: Path) -> None:
    ns = "/sdhn_dec"
    actors = [actor_cmd(i, N, ns, weights_file=weights, seed=7) for i in range(N)]
    with observer(N, ns) as (node, seen, spin), node_processes(*actors) as procs:
        for p in procs:
            assert p.wait_for_line("ready", timeout=30), p.output
        pids = {p.proc.pid for p in procs}
        assert len(pids) == N and os.getpid() not in pids, "one OS process per robot"

        def subscribed(i: int) -> set[str]:
            try:
                return {t for t, _ in node.get_subscriber_names_and_types_by_node(
                    "actor", f"{ns}/robot_{i}")}
            except NodeNameNonExistentError:  # not discovered yet
                return set()

        expected = {i: {f"{ns}/robot_{i}/obs", f"{ns}/policy/weights"}
                    for i in range(N)}
        assert spin(20, lambda: all(subscribed(i) == expected[i] for i in range(N))), (
            f"actor subscriptions: { {i: sorted(subscribed(i)) for i in range(N)} }")
        for i in range(N):
            published = {t for t, _ in node.get_publisher_names_and_types_by_node(
                "actor", f"{ns}/robot_{i}")}
            assert f"{ns}/robot_{i}/action" in published
            others = {t for t in published if "/robot_" in t and f"/robot_{i}/" not in t}
            assert not others, f"actor {i} publishes to other robots' topics: {others}"
        # Every action publisher is matched with the observer before the simulator starts.
        assert spin(20, lambda: all(node.count_publishers(f"{ns}/robot_{i}/action") >= 1
                                    for i in range(N)))
        with node_processes(sim_cmd(ns=ns, episodes=1, max_steps=STEPS, seed=3,
                                    extra_subscribers=1,
                                    step_deadline=EXACT_DEADLINE_S)) as (sim,):
            assert spin(40, lambda: len(seen.episodes) == 1), f"no episode:\n{sim.output}"
            sim.proc.wait(timeout=10)
        assert sim.proc.returncode == 0, sim.output
        stop_all(procs)
        ep = seen.episodes[0]
        assert ep.missed_actions == 0, sim.output
        version = json.loads(weights.with_suffix(".json").read_text())["version"]
        assert ep.policy_version == version, "actions must carry the weights version"
        assert {v for _a, v in seen.actions.values()} == {version}
        for s in range(ep.length):
            for r in range(N):
                assert (0, s, r) in seen.actions, f"no action of robot {r} at step {s}"
        assert len(seen.actions) == ep.length * N
        assert seen.state_count == ep.length + 1


@pytest.mark.parametrize("params,field", [
    ({"env": "maif-99"}, "env:"),
    ({"step_deadline": 0.0}, "step_deadline:"),
    ({"episodes": -1}, "episodes:"),
])
def test_sim_rejects_bad_parameters_before_any_topic(params: dict[str, object], field: str) -> None:
    env = params.pop("env", "maif-tiny")
    t0 = time.monotonic()
    done = subprocess.run(sim_cmd(str(env), **params), capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 2, done.stderr
    assert field in done.stderr and "allowed" in done.stderr, done.stderr
    assert "ready" not in done.stderr + done.stdout
    assert time.monotonic() - t0 < 30


@pytest.mark.parametrize("params,field", [
    ({"robot_id": 4}, "robot_id:"),
    ({"weights_file": "/nonexistent/actor.safetensors"}, "weights_file:"),
    ({"temperature": 0.0}, "temperature"),
    ({"break_stalls": "true", "greedy": "false"}, "break_stalls:"),
    ({"break_stalls": "true", "greedy": "true", "stall_rule": "3,x,3"}, "stall_rule:"),
    ({"dead_reckoning": "true"}, "dead_reckoning:"),  # no env: no grid to reckon on
    ({"final_approach": "true", "greedy": "true", "env": "maif-tiny"}, "final_approach:"),
    ({"final_approach": "true", "greedy": "true", "break_stalls": "true"}, "final_approach:"),
    ({"final_approach": "true", "greedy": "true", "break_stalls": "true", "env": "rware-3"},
     "final_approach:"),
])
def test_actor_rejects_bad_parameters(params: dict[str, object], field: str) -> None:
    args = actor_cmd(0, N)
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0], done.stderr  # one line naming the field


def test_actor_process_never_imports_torch(weights: Path) -> None:
    code = (
        "import sys, rclpy\n"
        "from rclpy.context import Context\n"
        "import sdhn_policy.actor_node as a\n"
        "c = Context(); rclpy.init(args=['actor', '--ros-args', '-p', 'robot_id:=1', '-p',"
        f" 'num_robots:=4', '-p', 'weights_file:={weights}'], context=c)\n"
        "n = a.ActorNode(c); print('TORCH', 'torch' in sys.modules); n.destroy_node()\n"
        "rclpy.try_shutdown(context=c)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          check=False)
    assert "TORCH False" in done.stdout, done.stdout + done.stderr


def test_actor_takes_latched_weights_and_drops_bad_ones(weights: Path) -> None:
    from sdhn_base.ros.qos import LATCHED
    from sdhn_msgs.msg import PolicyWeights
    from sdhn_policy.weights import load_actor_file

    blob = load_actor_file(weights)
    ns = "/sdhn_latched"
    with observer(N, ns) as (node, _seen, spin), node_processes(actor_cmd(1, N, ns)) as (actor,):
        assert actor.wait_for_line("ready", timeout=30), actor.output
        pub = node.create_publisher(PolicyWeights, f"{ns}/policy/weights", LATCHED)
        assert spin(20, lambda: pub.get_subscription_count() >= 1)
        assert node.count_publishers(f"{ns}/robot_1/action") == 0, "no weights, no topics"
        bad = PolicyWeights(version=blob.version, format=blob.format, payload=blob.payload,
                            sha256="0" * 64)
        pub.publish(bad)
        assert actor.wait_for_line("dropped (bad_sha256)", timeout=10), actor.output
        pub.publish(PolicyWeights(version=blob.version, format=blob.format,
                                  payload=blob.payload, sha256=blob.sha256))
        assert actor.wait_for_line(f"weights version {blob.version} accepted", timeout=10)
        assert spin(10, lambda: node.count_publishers(f"{ns}/robot_1/action") == 1)
        assert actor.stop() == 0, actor.output
