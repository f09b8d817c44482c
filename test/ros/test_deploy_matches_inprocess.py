"""Deployment equals the in-process policy: with the same exported weights, seed and greedy
actions, the ROS run (simulator + one actor process per robot) applies exactly the action
sequence of an in-process rollout, step for step, over two episodes."""

from __future__ import annotations

from pathlib import Path

import pytest

from sdhn_base.ros import topics
from sdhn_policy.onnx_export import write_onnx
from sdhn_policy.weights import decode_weights, load_actor_file

from .deploy_helpers import (
    EXACT_DEADLINE_S,
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
    actors = [actor_cmd(i, N, ns, weights_file=weights_file, greedy=True, backend=backend,
                        action_readers=2)  # the simulator and the observer
              for i in range(N)]
    with observer(N, ns) as (node, seen, spin), node_processes(*actors) as procs:
        actions = [topics.absolute(ns, topics.robot_action(i)) for i in range(N)]
        assert spin(30, lambda: all(node.count_publishers(t) >= 1 for t in actions)), [
            p.output for p in procs]
        with node_processes(sim_cmd(ns=ns, seed=SEED, episodes=EPISODES, max_steps=MAX_STEPS,
                                    extra_subscribers=1,
                                    step_deadline=EXACT_DEADLINE_S)) as (sim,):
            assert spin(60, lambda: len(seen.episodes) == EPISODES), sim.output
            sim.proc.wait(timeout=10)
        stop_all(procs)
    assert all(ep.missed_actions == 0 for ep in seen.episodes), sim.output
    for e in range(EPISODES):
        got = action_table(seen, e, N)
        assert len(got) == len(expected[e]) == seen.episodes[e].length
        for t, (a, b) in enumerate(zip(got, expected[e], strict=True)):
            assert a == b, f"episode {e} step {t}: ROS actions {a}, in-process {b}"


@pytest.mark.parametrize("gru_hidden", [64, 0], ids=["recurrent", "feed_forward"])
def test_rware_ros_deploy_equals_inprocess_greedy_rollout(tmp_path: Path, gru_hidden: int) -> None:
    """RWARE over ROS (the simulator node on rware-tiny-2ag, one actor process per robot) applies
    the in-process greedy rollout's actions step for step, so it delivers what it delivers in
    process on the same seed; with a recurrent and a feed-forward actor."""
    import torch

    from sdhn_policy.actor_torch import Actor
    from sdhn_policy.weights import ActorSpec, save_actor_file
    from sdhn_sim.envs import make_single_env

    env = make_single_env("rware-tiny-2ag", seed=SEED)
    n = env.num_robots
    weights = tmp_path / "actor.safetensors"
    steps = 60
    # Random weights often turn on the spot forever; take the first init (of a fixed few) whose
    # greedy rollout uses several actions, so the comparison below can tell actions apart.
    for init in range(20):
        torch.manual_seed(init)
        actor = Actor(ActorSpec(obs_size=env.obs_size, num_actions=env.num_actions,
                                num_robots=n, use_robot_id=True, gru_hidden=gru_hidden))
        with torch.no_grad():  # the head starts near zero: noise for input-dependent actions
            for t in actor.parameters():
                t.add_(torch.randn_like(t))
        save_actor_file(weights, actor.export(version=2))
        expected = inprocess_greedy_actions(weights, "rware-tiny-2ag", SEED, 1, steps)
        if len({a for step in expected[0] for a in step}) >= 3:
            break
    else:
        pytest.fail("no random init of 20 gives a policy that uses 3 actions")
    ns = f"/sdhn_equal_rware_{gru_hidden}"
    actors = [actor_cmd(i, n, ns, weights_file=weights, greedy=True, action_readers=2)
              for i in range(n)]  # action readers: the simulator and the observer
    with observer(n, ns) as (node, seen, spin), node_processes(*actors) as procs:
        actions = [topics.absolute(ns, topics.robot_action(i)) for i in range(n)]
        assert spin(30, lambda: all(node.count_publishers(t) >= 1 for t in actions)), [
            p.output for p in procs]
        with node_processes(sim_cmd("rware-tiny-2ag", ns=ns, seed=SEED, episodes=1,
                                    max_steps=steps, extra_subscribers=1,
                                    step_deadline=EXACT_DEADLINE_S)) as (sim,):
            assert spin(60, lambda: len(seen.episodes) == 1), sim.output
            sim.proc.wait(timeout=10)
        stop_all(procs)
    assert seen.episodes[0].missed_actions == 0, sim.output
    got = action_table(seen, 0, n)
    assert got == expected[0]
