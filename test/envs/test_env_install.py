"""The environments install alone from the repository into a fresh virtualenv (``pip install
--no-deps ./src/sdhn_sim`` plus NumPy, PettingZoo, Gymnasium and their small dependencies at the
locked versions) and work there without ROS or torch: scripts/check_env_install.py, run for real
(a new venv, a real pip install, PettingZoo's API test inside it)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_environments_install_alone_into_a_fresh_venv(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "check_env_install.py"),
                           "--keep", str(tmp_path / "venv")],
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    setup = (ROOT / "src" / "sdhn_sim" / "setup.py").read_text()
    version = re.search(r'version="([^"]+)"', setup)
    assert version is not None and result["version"] == version.group(1), result
    assert result["heavy_modules"] == [], result  # no rclpy, torch, mcap, yaml, sdhn_msgs
    assert result["rware_obs_shape"] == [2, 71], result
    episode = result["episode"]
    assert all(isinstance(v, int | float) for v in episode.values()), episode
    # nothing else of the project is in the new venv
    site = next((tmp_path / "venv" / "lib").glob("python3*/site-packages"))
    assert not [p.name for p in site.iterdir() if p.name.startswith(("sdhn_policy", "sdhn_train",
                                                                     "rclpy", "torch"))]
