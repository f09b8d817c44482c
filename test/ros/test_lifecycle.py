"""Managed actors, driven from another process through the standard lifecycle_msgs services:
a real actor process started ``managed:=true`` next to a real simulator (maif-tiny) and three
plain actors. The test process is the manager (its own rclpy node calling ChangeState/GetState,
as nav2's lifecycle manager would); ``ros2 lifecycle`` (our CLI) is a third process.

- unconfigured / inactive: no action publisher, so the simulator does not start;
- active: actions flow; deactivate: none after the reply, the simulator counts this robot's steps
  as missed and its /diagnostics turn WARN; activate again: actions flow again;
- cleanup, shutdown: the process ends with exit code 0;
- configure with bad weights: the transition fails, the node stays unconfigured and alive.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from sdhn_base.ros import topics

from .deploy_helpers import actor_cmd, sim_cmd, stop_all
from .processes import ROS2, node_processes

N = 4
LEVEL_WARN = b"\x01"


class Manager:
    """The test's rclpy node: lifecycle client, and subscriber of robot 0's actions, the team
    state and /diagnostics."""

    def __init__(self, ns: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile

        from sdhn_base.ros.lifecycle_client import LifecycleClient
        from sdhn_base.ros.qos import DIAGNOSTICS, STEP
        from sdhn_msgs.msg import RobotAction, TeamState

        self.client = LifecycleClient("test_manager")
        node = self.client.node
        deep = QoSProfile(history=STEP.history, depth=65536, reliability=STEP.reliability,
                          durability=STEP.durability)
        self.actions: list[Any] = []
        self.states: list[Any] = []
        self.diagnostics: list[Any] = []
        self.action_topic = topics.absolute(ns, topics.robot_action(0))
        node.create_subscription(RobotAction, self.action_topic, self.actions.append, deep)
        node.create_subscription(TeamState, topics.absolute(ns, topics.STATE),
                                 self.states.append, deep)
        node.create_subscription(
            DiagnosticArray, topics.DIAGNOSTICS,
            lambda m: self.diagnostics.extend((time.time(), s) for s in m.status), DIAGNOSTICS)

    def spin(self, seconds: float, until: Callable[[], bool]) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.client.spin(0.02)
            if until():
                return True
        return False

    def change(self, node: str, transition: str) -> bool | None:
        from sdhn_base.ros.lifecycle_client import change_state

        return change_state(self.client, node, transition, timeout_s=20)

    def state(self, node: str) -> str | None:
        from sdhn_base.ros.lifecycle_client import get_state

        return get_state(self.client, node, timeout_s=20)


@pytest.fixture
def manager(request: pytest.FixtureRequest) -> Any:
    m = Manager(request.param)
    yield m
    m.client.close()


def stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


@pytest.mark.parametrize("manager", ["/sdhn_lc"], indirect=True)
def test_managed_actor_acts_only_while_active(weights: Path, manager: Manager) -> None:
    ns, m = "/sdhn_lc", manager
    actor = f"{ns}/robot_0/actor"
    cmds = [actor_cmd(0, N, ns, weights_file=weights, managed=True),
            *(actor_cmd(i, N, ns, weights_file=weights) for i in range(1, N)),
            sim_cmd(ns=ns, episodes=0, max_steps=25, step_deadline=0.3, seed=3)]
    with node_processes(*cmds) as procs:
        managed, sim = procs[0], procs[-1]
        assert m.state(actor) == "unconfigured", managed.output
        node = m.client.node
        others = [topics.absolute(ns, topics.robot_action(i)) for i in range(1, N)]
        assert m.spin(40, lambda: all(node.count_publishers(t) == 1 for t in others)), (
            [p.output for p in procs])
        # Unconfigured, then configured but inactive: no action publisher, no step 0.
        assert node.count_publishers(m.action_topic) == 0
        assert m.change(actor, "configure") is True, managed.output
        assert m.state(actor) == "inactive"
        m.spin(1.0, lambda: False)
        assert node.count_publishers(m.action_topic) == 0 and not m.states, sim.output

        assert m.change(actor, "activate") is True, managed.output
        assert m.state(actor) == "active"
        assert m.spin(60, lambda: len(m.actions) >= 10), (len(m.actions), sim.output)

        assert m.change(actor, "deactivate") is True, managed.output
        t_off = time.time()  # the reply came: nothing may be sent after this
        n_states = len(m.states)
        assert m.spin(30, lambda: sum(s.missed_actions >= 1 for s in m.states[n_states:]) >= 5), (
            sim.output)
        assert all(stamp(a) <= t_off for a in m.actions), "an action after deactivate"
        # The simulator's diagnostics say WARN, naming the missed actions.
        sim_name = f"{ns}/sim"

        def sim_warns() -> bool:
            return any(s.name == sim_name and s.level == LEVEL_WARN and t > t_off
                       and "missed_actions_in_window" in s.message for t, s in m.diagnostics)

        assert m.spin(10, sim_warns), [(s.name, s.level, s.message) for _, s in m.diagnostics]
        actor_status = [s for _, s in m.diagnostics if s.name == actor]
        assert actor_status and {kv.key: kv.value for kv in actor_status[-1].values}[
            "lifecycle_state"] == "inactive", actor_status[-1:]

        assert m.change(actor, "activate") is True, managed.output
        t_on = time.time()
        assert m.spin(30, lambda: any(stamp(a) > t_on for a in m.actions)), managed.output

        for transition, state in (("deactivate", "inactive"), ("cleanup", "unconfigured")):
            assert m.change(actor, transition) is True, managed.output
            assert m.state(actor) == state
        assert m.change(actor, "shutdown") is True, managed.output
        assert managed.proc.wait(timeout=15) == 0, managed.output
        stop_all(procs[1:])


def bad_weights_file(tmp_path: Path, case: str) -> tuple[Path, dict[str, Any], str]:
    """(file, extra actor parameters, a word the configure error must name)."""
    if case == "fifo":  # opening it blocked the executor: lifecycle services stopped answering
        fifo = tmp_path / "actor.safetensors"
        os.mkfifo(fifo)
        (tmp_path / "actor.json").write_text("{}")
        return fifo, {}, "not a regular file"
    if case == "crafted_onnx":  # hidden_out [X, 3] passed configure, then killed the actor
        from faults.crafted_onnx import Craft, crafted

        from sdhn_policy.weights import ActorSpec

        spec = ActorSpec(obs_size=57, num_actions=5, hidden_sizes=(8,), gru_hidden=4)
        onnx_file = tmp_path / "actor.onnx"
        onnx_file.write_bytes(crafted(Craft(hidden_width=3), spec))
        return onnx_file, {"backend": "onnx"}, "hidden_out"
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    return bad, {}, "weights_file"


@pytest.mark.parametrize("case", ["garbage", "fifo", "crafted_onnx"])
@pytest.mark.parametrize("manager", ["/sdhn_lc_bad"], indirect=True)
def test_configure_with_bad_weights_fails_and_the_node_stays_alive(
        tmp_path: Path, manager: Manager, case: str) -> None:
    ns, m = "/sdhn_lc_bad", manager
    actor = f"{ns}/robot_0/actor"
    bad, params, named = bad_weights_file(tmp_path, case)
    with node_processes(actor_cmd(0, N, ns, weights_file=bad, managed=True, **params)) as (proc,):
        assert m.change(actor, "configure") is False, proc.output
        assert m.state(actor) == "unconfigured"
        assert proc.proc.poll() is None, proc.output
        assert proc.wait_for_line("configure failed: weights_file:", timeout=5), proc.output
        failed = [ln for ln in proc.lines if "configure failed" in ln]
        assert len(failed) == 1 and named in failed[0], proc.output
        # Another process, with our ros2 CLI (ros2cli has no wheels), sees the same.
        got = subprocess.run([*ROS2, "lifecycle", "get", actor], capture_output=True, text=True,
                             timeout=60, check=False)
        assert (got.returncode, got.stdout.strip()) == (0, "unconfigured"), got
        done = subprocess.run([*ROS2, "lifecycle", "set", actor, "shutdown"],
                              capture_output=True, text=True, timeout=60, check=False)
        assert (done.returncode, done.stdout.strip()) == (0, "Transitioning successful"), done
        assert proc.proc.wait(timeout=15) == 0, proc.output
