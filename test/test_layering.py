"""The layering the architecture promises: the core (environments, networks, algorithms, the
actor's NumPy runtime) imports neither rclpy nor ROS messages, so it trains and evaluates
without a ROS install; only node files, recording code and ``sdhn_sim.ros`` do."""

from __future__ import annotations

import subprocess
import sys

CORE = ["sdhn_sim.envs", "sdhn_sim.lockstep", "sdhn_sim.drops", "sdhn_policy.actor_core",
        "sdhn_policy.actor_runtime", "sdhn_train.trainer", "sdhn_train.transitions",
        "sdhn_train.cli"]


def test_core_modules_import_no_ros() -> None:
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE)
            + "print(sorted(m for m in sys.modules if m.split('.')[0] in "
              "('rclpy', 'sdhn_msgs', 'lifecycle_msgs', 'diagnostic_msgs')))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
