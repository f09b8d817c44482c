"""The standard interfaces beside ours, from a real short run (simulator, 4 actor processes,
recorder on maif-tiny): every node publishes diagnostic_msgs/DiagnosticArray on /diagnostics
about once a second with the documented keys; the simulator publishes the robots as a
geometry_msgs/PoseArray (frame map, cell centres as the viewer draws them) and each actor its
next target cell as geometry_msgs/PoseStamped, consistent with the team state and the action."""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from sdhn_base.ros import topics
from sdhn_sim.envs.maif import ACTION_DELTAS
from sdhn_sim.poses import cell_center

from .deploy_helpers import actor_cmd, sim_cmd, stop_all
from .own_node import own_node_and_executor
from .processes import ROS2, node_processes

N = 4
NS = "/sdhn_std"
KEYS = {  # node -> keys its diagnostics must carry (docs/lifecycle-and-diagnostics.md)
    f"{NS}/sim": {"steps_per_s", "missed_actions", "missed_actions_in_window",
                  "missed_fraction_in_window", "dropped_in_window"},
    f"{NS}/recorder": {"write_queue_depth", "not_written", "messages_written",
                       "dropped_in_window"},
    **{f"{NS}/robot_{i}/actor": {"lifecycle_state", "weights_version", "decisions",
                                 "decision_latency_p50_ms", "decision_latency_p99_ms",
                                 "dropped_in_window"} for i in range(N)},
}


def stamp_ns(m: Any) -> int:
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def test_diagnostics_poses_and_target_poses(weights: Path, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseArray, PoseStamped
    from rclpy.qos import QoSProfile

    from sdhn_base.ros.qos import DIAGNOSTICS, POSES, STEP
    from sdhn_msgs.msg import RobotAction, TeamState

    deep = QoSProfile(history=STEP.history, depth=65536, reliability=STEP.reliability,
                      durability=STEP.durability)
    diag: dict[str, list[tuple[float, Any]]] = defaultdict(list)
    states: dict[int, Any] = {}
    poses: dict[int, Any] = {}
    actions: dict[int, Any] = {}  # stamp -> action
    targets: dict[int, Any] = {}  # stamp -> target pose

    def on_diag(m: Any) -> None:
        for s in m.status:
            diag[s.name].append((time.monotonic(), s))

    recorder = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-r", f"__ns:={NS}",
                "-p", f"team_ns:={NS}", "-p", f"output:={tmp_path / 'run.mcap'}"]
    cmds = [sim_cmd(ns=NS, episodes=0, max_steps=30, step_deadline=0.5, seed=5,
                    extra_subscribers=1),
            # action readers: the simulator, the recorder and this test's node
            recorder, *(actor_cmd(i, N, NS, weights_file=weights, env="maif-tiny",
                                  action_readers=3) for i in range(N))]
    with own_node_and_executor("test_standard") as (node, ex):
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diag, DIAGNOSTICS)
        node.create_subscription(TeamState, topics.absolute(NS, topics.STATE),
                                 lambda m: states.__setitem__(stamp_ns(m), m), deep)
        node.create_subscription(PoseArray, topics.absolute(NS, topics.POSES),
                                 lambda m: poses.__setitem__(stamp_ns(m), m), POSES)
        for i in range(N):
            node.create_subscription(RobotAction, topics.absolute(NS, topics.robot_action(i)),
                                     lambda m: actions.__setitem__(stamp_ns(m), m), deep)
            node.create_subscription(PoseStamped,
                                     topics.absolute(NS, topics.robot_target_pose(i)),
                                     lambda m: targets.__setitem__(stamp_ns(m), m), POSES)
        with node_processes(*cmds) as procs:
            def enough() -> bool:
                return (all(len(diag[name]) >= 3 for name in KEYS) and len(poses) >= 10
                        and len(targets) >= 10 * N)

            end = time.monotonic() + 90
            while time.monotonic() < end and not enough():
                ex.spin_once(timeout_sec=0.05)
            assert enough(), ({k: len(v) for k, v in diag.items()}, len(poses), len(targets),
                              [p.output[-2000:] for p in procs])
            stop_all(procs)

    for name, keys in KEYS.items():
        got = diag[name]
        last = {kv.key for kv in got[-1][1].values}
        assert keys <= last, (name, keys - last)
        assert got[-1][1].hardware_id == NS
        # about 1 Hz: one array per period, never a burst per step
        span = got[-1][0] - got[0][0]
        assert len(got) <= span + 3, (name, len(got), span)
    actor_values = {kv.key: kv.value for kv in diag[f"{NS}/robot_0/actor"][-1][1].values}
    assert float(actor_values["decision_latency_p99_ms"]) > 0, actor_values
    assert actor_values["lifecycle_state"] == "active" and actor_values["weights_version"] != "0"

    # PoseArray: robot i at index i, the centre of its cell, same stamp as its TeamState.
    matched = 0
    for st, p in poses.items():
        if st not in states:
            continue
        assert p.header.frame_id == "map" and len(p.poses) == N
        cells = list(states[st].positions)
        for i, pose in enumerate(p.poses):
            assert (pose.position.x, pose.position.y) == cell_center(cells[2 * i],
                                                                    cells[2 * i + 1])
        matched += 1
    assert matched >= 5, (matched, len(poses), len(states))

    # Target pose: the cell the robot's action of step t moves to from its step-t cell.
    by_step = {(s.episode, s.step): s for s in states.values()}
    checked = 0
    for st, t in targets.items():
        a = actions.get(st)
        s = by_step.get((a.episode, a.step)) if a is not None else None
        if s is None:
            continue
        x, y = s.positions[2 * a.robot_id], s.positions[2 * a.robot_id + 1]
        dx, dy = ACTION_DELTAS[a.action]
        assert t.header.frame_id == "map"
        assert (t.pose.position.x, t.pose.position.y) == cell_center(x + dx, y + dy), (a, s)
        checked += 1
    assert checked >= 10, (checked, len(targets), len(actions))

    # The recorder took the team's topics but not the derived viewer streams (docs page).
    from mcap.reader import make_reader

    with (tmp_path / "run.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    recorded = {c.topic for c in summary.channels.values()}
    assert topics.absolute(NS, topics.STATE) in recorded, recorded
    assert not {t for t in recorded if t.endswith(("/poses", "/target_pose"))}, recorded
