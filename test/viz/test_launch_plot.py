"""The launcher's plot reads the reward the simulator named and puts success/makespan first."""

from __future__ import annotations

import json
from pathlib import Path

from sdhn_bringup.plot import plot_run, reward_name


def _run(tmp: Path, reward: str | None) -> Path:
    (tmp / "status").mkdir(parents=True)
    started = {"event": "started", "robots": 4, **({"reward": reward} if reward else {})}
    (tmp / "status" / "sim-events.jsonl").write_text(
        "not json\n" + json.dumps(started) + "\n" + json.dumps({"event": "done"}) + "\n")
    (tmp / "episodes.csv").write_text(
        "episode,completed,makespan,return,length\n0,True,17,3.5,17\n1,False,NC,-9.0,500\n")
    return tmp


def test_reward_name_comes_from_the_started_event(tmp_path: Path) -> None:
    assert reward_name(_run(tmp_path / "a", "corrected")) == "corrected"
    assert reward_name(_run(tmp_path / "b", None)) == "?"  # an older simulator did not say
    assert reward_name(tmp_path / "missing") == "?"


def test_plot_is_written(tmp_path: Path) -> None:
    run = _run(tmp_path, "reference")
    out = plot_run(run, train_run=run)
    assert out.exists() and out.stat().st_size > 1000, f"plot {out} is missing or empty"
