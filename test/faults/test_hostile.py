"""Malformed and hostile messages, one kind at a time, against real node processes.

Each kind is dropped, counted per kind (the node's stop line), logged once per kind with the
reason, and the node keeps working afterwards. The test process plays the simulator (against an
actor) or two of the robots (against the simulator), so it controls exactly what arrives when.
"""

from __future__ import annotations

import re
import signal
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.duration import Duration
from ros.deploy_helpers import actor_cmd, sim_cmd
from ros.processes import node_processes

from sdhn_base.polling import wait_until
from sdhn_base.ros import topics
from sdhn_base.ros.qos import LATCHED, STEP
from sdhn_msgs.msg import PolicyWeights, RobotAction, RobotObservation, TeamState
from sdhn_policy.weights import ActorSpec, decode_weights, encode_actor, save_actor_file

from .graph import Peer
from .hostile import action_msg, hostile_weights, obs_msg, weights_msg

pytestmark = pytest.mark.ros
NS = "/f_hostile_actor"  # one namespace per test (see test_kills.test_ns)
SIM_NS = "/f_hostile_sim"
N = 4  # maif-tiny


def tiny_weights(tmp: Path, version: int = 1) -> tuple[Path, Any]:
    """A random actor for maif-tiny (no training needed: we test plumbing, not skill)."""
    from sdhn_sim.envs import make_single_env

    env = make_single_env("maif-tiny", seed=0)
    spec = ActorSpec(obs_size=env.obs_size, num_actions=env.num_actions, hidden_sizes=(16,),
                     gru_hidden=16)
    rng = np.random.default_rng(0)
    tensors = {k: rng.normal(0, 0.3, s).astype(np.float32)
               for k, s in spec.tensor_shapes().items()}
    blob = encode_actor(spec, tensors, version)
    path = tmp / "actor.safetensors"
    save_actor_file(path, blob)
    return path, blob


def drop_lines(output: str, prefix: str) -> Counter[str]:
    """How many times each kind was *logged* (``prefix (kind)`` lines)."""
    return Counter(re.findall(re.escape(prefix) + r" \((\w+)\)", output))


def stop_counts(output: str, marker: str) -> dict[str, int]:
    """The per-kind counts of the node's stop line, e.g. ``drops: {'stale_step': 2}``."""
    line = next((ln for ln in output.splitlines() if marker in ln), "")
    return {k: int(v) for k, v in re.findall(r"'(\w+)': (\d+)", line)}


def test_actor_drops_each_malformed_obs_and_weights_kind(tmp_path: Path) -> None:
    weights_file, good = tiny_weights(tmp_path)
    obs_size = decode_weights(good)[0].obs_size
    marker = tmp_path / "pickle-ran"
    peer = Peer("fake_sim")
    got: list[RobotAction] = []
    obs_topic, action_topic = (topics.absolute(NS, topics.robot_obs(1)),
                               topics.absolute(NS, topics.robot_action(1)))
    obs_pub = peer.node.create_publisher(RobotObservation, obs_topic, STEP)
    w_pub = peer.node.create_publisher(PolicyWeights, topics.absolute(NS, topics.WEIGHTS), LATCHED)
    peer.node.create_subscription(RobotAction, action_topic, got.append, STEP)
    peer.start()
    rng = np.random.default_rng(1)
    good_obs = rng.uniform(0, 1, obs_size).astype(np.float32)

    def answer(episode: int, step: int, timeout: float = 10.0) -> RobotAction | None:
        """Send a valid obs; its action (same episode/step), proving every earlier obs was
        handled (one topic, in order)."""
        obs_pub.publish(obs_msg(episode, step, 1, N, good_obs))
        ok = wait_until(lambda: any((a.episode, a.step) == (episode, step) for a in got),
                        timeout, poll=0.01)
        if not ok:
            return None
        return next(a for a in got if (a.episode, a.step) == (episode, step))

    cmd = actor_cmd(1, N, ns=NS, weights_file=str(weights_file), greedy=True)
    try:
        with node_processes(cmd) as (actor,):
            assert actor.wait_for_line("ready", timeout=30), actor.output
            assert wait_until(lambda: obs_pub.get_subscription_count() >= 1
                              and peer.node.count_publishers(action_topic) >= 1, 20), (
                f"actor's obs/action topics never matched:\n{actor.output}")
            first = answer(0, 0)
            assert first is not None and first.policy_version == 1, (first, actor.output)
            # Observations: each kind twice, then a valid one must still be answered.
            bad_obs = {
                "wrong_obs_length": obs_msg(0, 1, 1, N, np.zeros(obs_size - 3)),
                "non_finite_obs": obs_msg(0, 1, 1, N, np.full(obs_size, np.nan)),
                "non_finite_obs:inf": obs_msg(0, 1, 1, N, np.full(obs_size, np.inf)),
                "wrong_robot": obs_msg(0, 1, 7, N, good_obs),
            }
            for msg in bad_obs.values():
                obs_pub.publish(msg)
                obs_pub.publish(msg)
            assert answer(0, 1) is not None, f"valid step 1 unanswered:\n{actor.output}"
            # Steps from the past and the future: dropped, and the real next step still goes.
            for ep, st in ((0, 1), (0, 1), (0, 9), (3, 5)):
                obs_pub.publish(obs_msg(ep, st, 1, N, good_obs))
            assert answer(0, 2) is not None, (
                f"step 2 unanswered after stale/future:\n{actor.output}")
            n_actions = len(got)
            # Weights: each hostile kind, acked, then an observation answered before the next:
            # the topic keeps only the last message, and the actor handles events in arrival
            # order, so the answer proves the weights message was taken (not overwritten).
            step = 3
            for kind, msg in hostile_weights(good, 2, marker).items():
                t0 = time.monotonic()
                w_pub.publish(msg)
                assert w_pub.wait_for_all_acked(Duration(seconds=20)), (
                    f"weights ({len(msg.payload)} B) not acked in 20 s")
                after = answer(0, step, timeout=30)
                assert after is not None and after.policy_version == 1, (
                    f"after {kind}: {after} (expected version 1 kept)\n{actor.output}")
                print(f"hostile weights {kind} ({len(msg.payload)} B) dropped, version 1 kept, "
                      f"in {time.monotonic() - t0:.2f} s")
                step += 1
            assert len(got) == n_actions + step - 3, "an action answered a dropped message"
            # Valid weights are still taken (between steps): version 2 within a few steps.
            w_pub.publish(encode_weights_msg(good, 2))
            v2, last = None, step + 26
            while step < last and v2 is None:
                a = answer(0, step)
                assert a is not None, f"step {step} unanswered:\n{actor.output}"
                v2 = a if a.policy_version == 2 else None
                step += 1
            assert v2 is not None, f"valid version 2 never used:\n{actor.output}"
            code = actor.stop(signal.SIGINT, timeout=10)
    finally:
        peer.close()
    out = actor.output
    assert code == 0, out
    assert not marker.exists(), "a weights payload executed code (pickle)"
    logged = drop_lines(out, "dropped")
    counts = stop_counts(out, "drops:")
    expected = {"wrong_obs_length": 2, "non_finite_obs": 4, "wrong_robot": 2, "stale_step": 2,
                "future_step": 2, "bad_sha256": 1, "bad_tensors": 2, "unknown_format": 1,
                "oversized_payload": 1, "bad_weights": 5}
    assert counts == expected, f"drop counts {counts}, expected {expected}\n{out}"
    assert logged == Counter(dict.fromkeys(expected, 1)), f"log lines per kind: {logged}\n{out}"
    print(f"actor drops {counts}; version 2 first used at step {v2.step}")


def encode_weights_msg(good: Any, version: int) -> PolicyWeights:
    spec, tensors = decode_weights(good)
    blob = encode_actor(spec, tensors, version)
    return weights_msg(blob.format, version, blob.payload, blob.sha256)


def test_sim_drops_each_hostile_action_kind(tmp_path: Path) -> None:
    """Robots 0 and 1 are real actors; the test plays robots 2 and 3. At two hostile steps robot
    2 stays silent (so only the deadline ends the step) and robot 3's topic carries an
    out-of-range action, a valid one, its duplicate, a stale and a future step and a wrong
    robot id, all in order on one topic: every one reaches the simulator inside the step."""
    weights_file, _ = tiny_weights(tmp_path)
    deadline = 0.5
    hostile_steps = {(0, 3), (0, 6)}
    peer = Peer("fake_robots")
    states: list[Any] = []
    pubs = {k: peer.node.create_publisher(RobotAction,
                                          topics.absolute(SIM_NS, topics.robot_action(k)), STEP)
            for k in (2, 3)}

    def on_obs(k: int, m: RobotObservation) -> None:
        if m.terminated or m.truncated:
            return
        e, t = int(m.episode), int(m.step)
        if (e, t) not in hostile_steps:
            pubs[k].publish(action_msg(e, t, k, 0))
        elif k == 3:
            for msg in (action_msg(e, t, 3, 200),  # out of range (uint8; 5 actions)
                        action_msg(e, t, 3, 0), action_msg(e, t, 3, 0),  # duplicate
                        action_msg(e, t - 1, 3, 0), action_msg(e, t + 5, 3, 0),
                        action_msg(e, t, 9, 0)):  # robot id 9 on robot 3's topic
                pubs[3].publish(msg)

    for k in (2, 3):
        peer.node.create_subscription(RobotObservation,
                                      topics.absolute(SIM_NS, topics.robot_obs(k)),
                                      lambda m, k=k: on_obs(k, m), STEP)
    peer.node.create_subscription(TeamState, topics.absolute(SIM_NS, topics.STATE), states.append,
                                  STEP)
    peer.start()
    cmds = [sim_cmd(ns=SIM_NS, episodes=0, step_deadline=deadline, max_steps=40,
                    start_timeout=30.0),
            *(actor_cmd(i, N, ns=SIM_NS, weights_file=str(weights_file), greedy=True)
              for i in (0, 1))]
    try:
        with node_processes(*cmds) as (sim, *actors):
            assert wait_until(lambda: any(int(s.step) >= 12 for s in states), 45), (
                f"sim did not reach step 12; states {len(states)}\n{sim.output}")
            code = sim.stop(signal.SIGINT, timeout=10)
            for a in actors:
                a.stop(signal.SIGINT)
    finally:
        peer.close()
    out = sim.output
    assert code == 0, out
    missed = {int(s.step): int(s.missed_actions) for s in states if int(s.episode) == 0}
    # The step after each hostile step was reached by the deadline with exactly robot 2 missing.
    assert missed.get(4) == 1 and missed.get(7) == 1, f"missed per step {missed}"
    assert all(v == 0 for s, v in missed.items() if s not in (4, 7)), f"missed {missed}"
    counts = stop_counts(out, "totals:")
    expected = {"duplicate_action": 2, "action_out_of_range": 2, "stale_step": 2, "future_step": 2,
                "unknown_robot": 2}
    assert counts == expected, f"sim drop counts {counts}, expected {expected}\n{out}"
    logged = drop_lines(out, "dropped action")
    assert logged == Counter(dict.fromkeys(expected, 1)), f"log lines per kind {logged}\n{out}"
    print(f"sim drops {counts}; missed per step {missed}")
