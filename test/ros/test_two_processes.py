"""Two real OS processes exchange sdhn_msgs over rclpy on localhost, in lock-step."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from .processes import node_processes

PEER = str(Path(__file__).with_name("peer.py"))


def test_observations_and_actions_cross_process_boundaries() -> None:
    steps = 25
    with node_processes(
        [sys.executable, PEER, "robot", "--timeout", "30"],
        [sys.executable, PEER, "sim", "--steps", str(steps), "--timeout", "25"],
    ) as (robot, sim):
        sim.proc.wait(timeout=40)
        assert sim.proc.returncode == 0, f"sim peer failed:\n{sim.output}\nrobot:\n{robot.output}"
    expected = [
        int((np.arange(57, dtype=np.float32) * 0.5 + s).astype(np.float32).sum()) % 5
        for s in range(steps)
    ]
    assert f"OK steps={steps} actions={expected}" in sim.output, sim.output
