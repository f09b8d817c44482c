"""Deployment equals the in-process policy: with the same exported weights, seed and greedy
actions, the ROS run (simulator + one actor process per robot) applies exactly the action
sequence of an in-process rollout, step for step, over two episodes."""

from __future__ import annotations

from pathlib import Path

import pytest

from sdhn_policy.onnx_export import write_onnx
from sdhn_policy.weights import decode_weights, load_actor_file
from sdhn_sim.ros import topics

from .deploy_helpers import (
    action_table,
    actor_cmd,
    inprocess_greedy_actions,
    observer,
    sim_cmd,
    stop_all,
)
from .processes import node_processes

N, SEED, EPISODES, MAX_STEPS = 4, 5, 2, 40


@pytest.mark.parametrize("backend", ["numpy", "onnx"])
def test_ros_deploy_actions_equal_inprocess_greedy_rollout(weights: Path, backend: str) -> None:
    """Either actor backend; the ONNX actors run an exported actor.onnx file as it is."""
    expected = inprocess_greedy_actions(weights, "maif-tiny", SEED, EPISODES, MAX_STEPS)
    ns = f"/sdhn_equal_{backend}"
    weights_file = weights
    if backend == "onnx":
        blob = load_actor_file(weights)
        spec, tensors = decode_weights(blob)
        weights_file = write_onnx(weights.with_name("actor.onnx"), spec, tensors, "maif",
                                  blob.version)
    actors = [actor_cmd(i, N, ns, weights_file=weights_file, greedy=True, backend=backend)
              for i in range(N)]
    with observer(N, ns) as (node, seen, spin), node_processes(*actors) as procs:
        actions = [topics.absolute(ns, topics.robot_action(i)) for i in range(N)]
        assert spin(30, lambda: all(node.count_publishers(t) >= 1 for t in actions)), [
            p.output for p in procs]
        with node_processes(sim_cmd(ns=ns, seed=SEED, episodes=EPISODES, max_steps=MAX_STEPS,
                                    extra_subscribers=1)) as (sim,):
            assert spin(60, lambda: len(seen.episodes) == EPISODES), sim.output
            sim.proc.wait(timeout=10)
        stop_all(procs)
    assert all(ep.missed_actions == 0 for ep in seen.episodes), sim.output
    for e in range(EPISODES):
        got = action_table(seen, e, N)
        assert len(got) == len(expected[e]) == seen.episodes[e].length
        for t, (a, b) in enumerate(zip(got, expected[e], strict=True)):
            assert a == b, f"episode {e} step {t}: ROS actions {a}, in-process {b}"
