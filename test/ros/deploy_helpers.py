"""Shared pieces of the deployment tests: exported weights, node commands, an in-process rollout,
and an rclpy observer node that records what the graph publishes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_base.ros import topics

from .own_node import own_node_and_executor
from .processes import ROS2

TEAM_NS = "/sdhn"
# Each test uses its own team namespace: a node killed by an earlier test lingers in the DDS graph
# until its lease expires, and must not count as a subscriber or publisher of the next test.
EXACT_DEADLINE_S = 60.0
# The simulator's step deadline in tests that compare a deployment with the in-process rollout or
# count missed actions: lock-step then waits for every action, so the outcome depends on no
# process's speed. At the default 1 s an actor starved at load ~20 missed a step, and the test
# failed on that alone (a flaky test_conditions_deploy run).


def export_weights(root: Path, env: str = "maif-tiny", seed: int = 1) -> Path:
    """Actor weights exported by a very short in-process ``train`` run (a real export)."""
    run = root / "train"
    done = subprocess.run(
        [sys.executable, "-m", "sdhn_train.cli", "--env", env, "--seed", str(seed),
         "--total-steps", "256", "--num-envs", "2", "--run-name", "t", "--no-progress",
         "--set", f"log.root={run}", "--set", "ppo.rollout_len=32", "--set", "eval.interval=0",
         "--set", "log.tensorboard=false", "--set", "ppo.num_minibatches=2"],
        capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0, f"train failed:\n{done.stdout}\n{done.stderr}"
    path = run / "t" / "actor.safetensors"
    assert path.is_file(), done.stderr
    return path


def sim_cmd(env: str = "maif-tiny", ns: str = TEAM_NS, **params: Any) -> list[str]:
    args = [*ROS2, "run", "sdhn_sim", "sim", "--ros-args", "-r", f"__ns:={ns}",
            "-p", f"team_ns:={ns}", "-p", f"env:={env}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={_ros(v)}"]
    return args


def actor_cmd(i: int, n: int, ns: str = TEAM_NS, **params: Any) -> list[str]:
    robot_ns = topics.absolute(ns, topics.robot(i))
    args = [*ROS2, "run", "sdhn_policy", "actor", "--ros-args", "-r", f"__ns:={robot_ns}",
            "-p", f"team_ns:={ns}", "-p", f"robot_id:={i}", "-p", f"num_robots:={n}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={_ros(v)}"]
    return args


def trainer_cmd(run_dir: Path, config: Path, env: str = "maif-tiny", **params: Any) -> list[str]:
    """The trainer node in the default team namespace unless ``team_ns`` is given."""
    args = [*ROS2, "run", "sdhn_train", "trainer", "--ros-args", "-p", f"env:={env}",
            "-p", f"run_dir:={run_dir}", "-p", f"config:={config}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={_ros(v)}"]
    return args


def status_watched_trainer(tmp_path: Path, monkeypatch: Any, ns: str) -> tuple[list[str], Path]:
    """A maif-tiny trainer command (one PPO epoch, no TensorBoard, 16-step rollouts) whose
    status file lands in the returned directory (``<status>/trainer.status.json``)."""
    status = tmp_path / "status"
    monkeypatch.setenv("SDHN_READY_FILE", str(status / "any.ready"))
    config = tmp_path / "trainer.yaml"
    config.write_text("ppo:\n  epochs: 1\nlog:\n  tensorboard: false\n")
    return trainer_cmd(tmp_path / "run", config, team_ns=ns, rollout_steps=16), status


def _ros(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def inprocess_greedy_actions(weights: Path, env: str, seed: int, episodes: int,
                             max_steps: int) -> list[list[list[int]]]:
    """[episode][step][robot] greedy actions of an in-process rollout: ``SingleEnv`` + the NumPy
    runtime, each robot stepping its own GRU from its own observation row."""
    from sdhn_policy.actor_runtime import ActorRuntime
    from sdhn_sim.envs import make_single_env

    rt = ActorRuntime.from_file(weights)
    sim = make_single_env(env, seed=seed, max_steps=max_steps)
    rng = np.random.default_rng(0)
    out: list[list[list[int]]] = []
    for _ in range(episodes):
        obs, _ = sim.reset()
        hs = [rt.initial_state(1) for _ in range(sim.num_robots)]
        steps: list[list[int]] = []
        while True:
            acts = []
            for i in range(sim.num_robots):
                a, _, hs[i] = rt.act(obs[i][None], hs[i], True, rng, robot_id=i)
                acts.append(int(a[0]))
            steps.append(acts)
            res = sim.step(np.array(acts))
            obs = res.obs
            if res.terminated or res.truncated:
                break
        out.append(steps)
    return out


@dataclass
class Seen:
    actions: dict[tuple[int, int, int], tuple[int, int]] = field(default_factory=dict)
    episodes: list[Any] = field(default_factory=list)
    obs_count: int = 0
    state_count: int = 0
    diagnostics: dict[str, list[Any]] = field(default_factory=dict)  # node name -> statuses


@contextmanager
def observer(num_robots: int, ns: str = TEAM_NS) -> Iterator[tuple[Any, Seen, Any]]:
    """An rclpy node in the test process that subscribes to every obs, action, state and episode
    topic (the simulator counts it with ``extra_subscribers=1``) and to /diagnostics. Yields
    (node, seen, spin)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile

    from sdhn_base.ros.qos import DIAGNOSTICS, STEP
    from sdhn_msgs.msg import EpisodeSummary, RobotAction, RobotObservation, TeamState

    # The test process is a starved observer on a loaded machine: a reader history as deep as a
    # whole test run, so samples it is slow to take are never overwritten in its own cache
    # (otherwise it can miss an action the recording and the trainer both have).
    qos = QoSProfile(history=STEP.history, depth=65536, reliability=STEP.reliability,
                     durability=STEP.durability)
    with own_node_and_executor("test_observer", EventsExecutor) as (node, ex):
        seen = Seen()

        def on_action(m: Any) -> None:
            key = (int(m.episode), int(m.step), int(m.robot_id))
            assert key not in seen.actions, f"duplicate action {key}"
            seen.actions[key] = (int(m.action), int(m.policy_version))

        def on_obs(_m: Any) -> None:
            seen.obs_count += 1

        def on_state(_m: Any) -> None:
            seen.state_count += 1

        subs = [node.create_subscription(
                    RobotAction, topics.absolute(ns, topics.robot_action(i)), on_action, qos)
                for i in range(num_robots)]
        subs += [node.create_subscription(
                     RobotObservation, topics.absolute(ns, topics.robot_obs(i)), on_obs, qos)
                 for i in range(num_robots)]
        subs.append(node.create_subscription(TeamState, topics.absolute(ns, topics.STATE),
                                             on_state, qos))
        subs.append(node.create_subscription(EpisodeSummary, topics.absolute(ns, topics.EPISODE),
                                             seen.episodes.append, qos))

        def on_diagnostics(m: Any) -> None:
            for status in m.status:
                seen.diagnostics.setdefault(status.name, []).append(status)

        subs.append(node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics,
                                             DIAGNOSTICS))

        def spin(seconds: float, until: Any = None) -> bool:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                ex.spin_once(timeout_sec=0.02)
                if until is not None and until():
                    return True
            return until is None

        yield node, seen, spin


def stop_all(procs: list[Any], timeout: float = 10.0) -> None:
    """SIGINT every node (they leave the graph cleanly) and wait; exit codes must be 0. A node
    still running ``timeout`` s after its SIGINT fails the test with where it is stuck."""
    for p in procs:
        if p.proc.poll() is None:
            p.proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    codes = []
    for p in procs:
        try:
            codes.append(p.proc.wait(timeout=max(deadline - time.monotonic(), 0.1)))
        except subprocess.TimeoutExpired:
            raise AssertionError(f"a node did not exit within {timeout} s of SIGINT: "
                                 f"{p.where()}") from None
    assert all(c == 0 for c in codes), (codes, [p.output for p in procs])


def action_table(seen: Seen, episode: int, num_robots: int) -> list[list[int]]:
    steps = sorted({s for (e, s, _r) in seen.actions if e == episode})
    return [[seen.actions[(episode, s, r)][0] for r in range(num_robots)] for s in steps]
