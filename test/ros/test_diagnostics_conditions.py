"""What the simulator's /diagnostics says about the world it runs (real processes: simulator on
the realtime clock under a lost-action condition with a fault schedule, 4 actor processes): the
clock mode, the active conditions and their counts, the staleness counts, and the robot its
silence failed. Counts and labels only, never timing."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from sdhn_base.ros import topics

from .deploy_helpers import actor_cmd, sim_cmd, stop_all
from .own_node import own_node_and_executor
from .processes import node_processes

N, NS = 4, "/sdhn_diag_cond"


def test_diagnostics_report_the_clock_conditions_and_failed_robots(weights: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray

    from sdhn_base.ros.qos import DIAGNOSTICS

    last: dict[str, dict[str, str]] = {}

    def on_diag(m: Any) -> None:
        for s in m.status:
            last[s.name] = {kv.key: kv.value for kv in s.values}

    # fail_after_missed 10 ticks (0.5 s): well above the missed ticks a loaded machine gives a
    # live robot, so only the cut robot 3 is declared failed (docs/running-the-stack.md)
    cmds = [sim_cmd(ns=NS, episodes=0, max_steps=40, seed=5, clock="realtime", rate_hz=20.0,
                    conditions="'{lost_actions: 0.2}'", fail_after_missed=10,
                    faults="'[{robot: 3, at_step: 5}]'"),
            *(actor_cmd(i, N, NS, weights_file=weights, realtime=True) for i in range(N))]
    sim_name, actor_name = f"{NS}/sim", f"{NS}/robot_0/actor"

    def enough() -> bool:
        # Every node asserted on below must have reported: the actors publish /diagnostics at
        # 1 Hz on their own clock, so the simulator's condition alone could be met (2 s in at
        # 20 Hz) before robot 0's first report arrived.
        # At least one: robot 3's actor is gone for good, so every later episode (40 steps,
        # 2 s) declares it failed again; a 1 Hz report can land in the second one.
        v = last.get(sim_name, {})
        return (int(v.get("silent_robots_failed", "0")) >= 1 and int(v.get("steps", "0")) >= 30
                and actor_name in last)

    with own_node_and_executor("test_diag_conditions") as (node, ex):
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diag, DIAGNOSTICS)
        with node_processes(*cmds) as procs:
            end = time.monotonic() + 90
            while time.monotonic() < end and not enough():
                ex.spin_once(timeout_sec=0.05)
            assert enough(), (last.get(sim_name), [p.output[-2000:] for p in procs])
            stop_all(procs)
    v = last[sim_name]
    assert v["clock"] == "realtime" and float(v["rate_hz"]) == 20.0
    assert v["conditions"] == "lost_actions=0.2"
    assert int(v["conditions/lost_actions"]) > 0 and int(v["conditions/steps"]) >= 30
    assert v["fault_cuts"] == "1" and int(v["failed_robots_now"]) >= 1
    # every applied action was counted by its staleness
    assert sum(int(x) for k, x in v.items() if k.startswith("staleness/")) > 0
    assert "stale_actions" in v and "late_ticks" in v
    assert "skipped_steps" in last[actor_name]
