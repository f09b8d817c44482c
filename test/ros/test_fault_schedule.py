"""Real faults over ROS: the launcher runs the shipped maif-tiny policy (simulator + one actor
process per robot, restart on failure), its fault schedule SIGKILLs robot 1's actor at step 3
and never restarts it, the simulator finds the robot silent and fails it, and each episode's
outcome in episodes.csv (ideal-team and survivors' success, makespans, failed robots) is the
in-process robot-failure outcome on the same instances."""

from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path

import pytest
from envs.test_silent_robots import in_process_with_failure

from sdhn_bringup.launch_load import LaunchConfigError, load_config

from .processes import node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]
SEED, ROBOT, AT_STEP, EPISODES, MAX_STEPS = 7, 1, 3, 2, 60


def outcome(row: dict[str, str]) -> tuple[bool, int | None, bool, int | None, int]:
    """An episodes.csv row as (completed, makespan, survivors' success, survivors' makespan,
    failed robots); the survivors' columns are empty when no robot failed (= the team's)."""
    def steps(text: str) -> int | None:
        return None if text == "NC" else int(text)

    completed, makespan = row["completed"] == "True", steps(row["makespan"])
    if not row["survivors_completed"]:
        return completed, makespan, completed, makespan, int(row["failed_robots"])
    return (completed, makespan, row["survivors_completed"] == "True",
            steps(row["survivors_makespan"]), int(row["failed_robots"]))


def test_a_killed_actor_fails_its_robot_as_in_process(tmp_path: Path) -> None:
    sets = [f"run_dir={tmp_path}", "recorder=false", f"seed={SEED}", f"episodes={EPISODES}",
            f"max_steps={MAX_STEPS}", "step_deadline=0.5", "fail_after_missed=2",
            f"faults=[{{robot: {ROBOT}, at_step: {AT_STEP}}}]",
            f"team_ns=/sdhn_faults_{os.getpid()}"]  # never a lingering run's
    args = [*LAUNCH, *(a for s in sets for a in ("--set", s))]
    with node_processes(args) as (launcher,):
        launcher.proc.wait(timeout=120)
    out = launcher.output
    assert launcher.proc.returncode == 0, out  # the killed actor is expected, not a failure
    assert f"fault schedule: killed actor_{ROBOT}" in out, out
    assert f"actor_{ROBOT} ended: killed by SIGKILL (fault schedule)" in out, out
    assert "restarted actor" not in out, out
    events = [json.loads(line) for line in
              (tmp_path / "status" / "sim-events.jsonl").read_text().splitlines()]
    (cut,) = [e for e in events if e["event"] == "fault"]
    assert (cut["robot"], cut["episode"], cut["step"]) == (ROBOT, 0, AT_STEP)
    failed = [e for e in events if e["event"] == "robot_failed"]
    assert [(e["robot"], e["since_step"]) for e in failed] == [(ROBOT, AT_STEP)]
    rows = list(csv.DictReader((tmp_path / "episodes.csv").read_text().splitlines()))
    got = [outcome(r) for r in rows]
    want = in_process_with_failure(SEED, ROBOT, AT_STEP, EPISODES, MAX_STEPS)
    assert got == want, (got, want)
    assert any(w[2] for w in want)  # the survivors succeed: the comparison has content


@pytest.mark.parametrize("sets,field", [
    (["faults=[{robot: 7, at_step: 3}]", "fail_after_missed=2"], "faults[0].robot"),
    (["faults=[{robot: 1, at_step: 3}]"], "fail_after_missed"),
    (["faults={robot: 1}"], "faults"),
    (["faults=[{robot: 1, at_step: 3}]", "fail_after_missed=2", "actor_hosts=2"], "faults"),
    (["conditions.latency=-1"], "conditions.latency"),
    (["conditions={lost: 0.1}"], "conditions.lost"),
])
def test_a_bad_fault_schedule_or_conditions_block_is_refused_before_anything_starts(
        sets: list[str], field: str) -> None:
    with pytest.raises(LaunchConfigError, match=field.replace("[", r"\[").replace("]", r"\]")):
        load_config(Path("configs/launch/deploy-tiny.yaml"), sets)
