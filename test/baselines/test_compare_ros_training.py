"""sdhn_experiments.bench.ros_vs_inprocess (scripts/compare_ros_training.py) without training:
its argument checks (one line naming the flag, exit 2, nothing written) and its table (success
and makespan first, NC when nothing completed, the return under the reward named)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sdhn_experiments.bench import ros_vs_inprocess

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "compare_ros_training.py"


@pytest.mark.parametrize(("args", "flag"), [
    (["--steps", "1000"], "--steps"),  # not a multiple of the rollout
    (["--steps", "64", "--rollout-steps", "128"], "--steps"),
    (["--rollout-steps", "1"], "--rollout-steps"),
    (["--seeds", "1", "1"], "--seeds"),
    (["--instances", "0"], "--instances"),
    (["--init-from", "no/such/actor.safetensors"], "--init-from"),
])
def test_bad_arguments_are_one_line_naming_the_flag(tmp_path: Path, args: list[str],
                                                    flag: str) -> None:
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, str(SCRIPT), *args, "--out", str(out)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2, done.stderr
    assert f"{flag}:" in done.stderr.splitlines()[-1], done.stderr
    assert not out.exists()


def test_an_existing_out_dir_is_refused(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2 and "--out:" in done.stderr, done.stderr


def test_table_puts_success_and_makespan_first_and_names_the_reward() -> None:
    evals = {"train": {"success_rate": 0.5, "makespan": 40.25, "return": -80.0},
             "heldout": {"success_rate": 0.0, "makespan": "NC", "return": -200.0}}
    runs = [ros_vs_inprocess.RunResult("init", None, 0, eval=evals),
            ros_vs_inprocess.RunResult("ros", 2, 65536, sim_steps=70001, eval=evals)]
    lines = ros_vs_inprocess.table(runs).splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header[:8] == ["mode", "seed", "steps learned", "sim steps", "success",
                          "held-out success", "makespan", "held-out makespan"]
    assert header[8] == "return (corrected)"
    row = [c.strip() for c in lines[3].strip("|").split("|")]
    assert row == ["ros", "2", "65,536", "70,001", "0.50", "0.00", "40.2", "NC", "-80.0",
                   "-200.0"]
    assert [c.strip() for c in lines[2].strip("|").split("|")][:4] == ["init", "—", "0", "—"]
