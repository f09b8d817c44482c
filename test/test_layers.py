"""The house's floors, one idea held two ways.

1. The packages stack in one direction: sdhn_base (shared utilities and ROS plumbing) at the
   bottom, then sdhn_sim (environments, simulator, recording, viz), sdhn_policy (the actor),
   sdhn_train (training), sdhn_experiments (suites, evaluation, reports) and sdhn_bringup (the
   launcher) on top. A module may import only its own package and the ones below it, so a
   newcomer reads the house floor by floor and the actor process never pulls in the trainer.
2. The cores (environments, the lock-step core, the actor's NumPy runtime, the trainer) import
   neither rclpy nor ROS messages, so they train and evaluate without a ROS install; only node
   files, recording code and ``sdhn_base.ros`` do.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
FLOORS = ("sdhn_base", "sdhn_sim", "sdhn_policy", "sdhn_train", "sdhn_experiments",
          "sdhn_bringup")
CORE = ["sdhn_sim.envs", "sdhn_sim.lockstep", "sdhn_base.drops", "sdhn_policy.actor_core",
        "sdhn_policy.actor_runtime", "sdhn_train.trainer", "sdhn_train.transitions",
        "sdhn_train.cli", "sdhn_experiments.experiments"]
ROS_PACKAGES = ("rclpy", "sdhn_msgs", "lifecycle_msgs", "diagnostic_msgs")


def _imported_packages(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_every_python_package_under_src_is_a_floor() -> None:
    found = {p.parent.name for p in SRC.glob("*/setup.py")}
    assert found == set(FLOORS), f"packages under src/ {sorted(found)} vs floors {FLOORS}"


@pytest.mark.parametrize("package", FLOORS)
def test_a_package_imports_only_itself_and_the_packages_below(package: str) -> None:
    above = set(FLOORS[FLOORS.index(package) + 1:])
    files = sorted((SRC / package / package).rglob("*.py"))
    assert files, f"no modules found for {package}"
    upward = {str(f.relative_to(SRC)): sorted(_imported_packages(f) & above) for f in files}
    assert not {f: p for f, p in upward.items() if p}, "imports that run up a floor"


def test_core_modules_import_no_ros() -> None:
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE)
            + f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_PACKAGES!r}))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
