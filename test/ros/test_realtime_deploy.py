"""The simulator's realtime clock with real processes: the launcher starts the simulator with
``clock: realtime`` and one actor process per robot, the world steps at its rate without waiting,
and every robot-step is accounted for: applied (with its staleness) or missed. Counts only: how
stale the actions are depends on the machine's load, never asserted."""

from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path

from sdhn_bringup.launch_graph import node_parameters
from sdhn_bringup.launch_load import load_config

from .processes import node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]
N, EPISODES, MAX_STEPS = 4, 2, 30


def test_realtime_deployment_accounts_for_every_robot_step(weights: Path, tmp_path: Path) -> None:
    sets = [f"weights={weights}", f"run_dir={tmp_path}", "recorder=false",
            f"max_steps={MAX_STEPS}", f"episodes={EPISODES}", "clock=realtime", "rate_hz=20.0",
            f"team_ns=/sdhn_realtime_{os.getpid()}"]
    args = [*LAUNCH, *(a for s in sets for a in ("--set", s))]
    with node_processes(args) as (launcher,):
        launcher.proc.wait(timeout=90)
    assert launcher.proc.returncode == 0, launcher.output
    rows = list(csv.DictReader((tmp_path / "episodes.csv").read_text().splitlines()))
    assert [r["episode"] for r in rows] == [str(e) for e in range(EPISODES)]
    events = [json.loads(line) for line in
              (tmp_path / "status" / "sim-events.jsonl").read_text().splitlines()]
    episodes = [e for e in events if e["event"] == "episode"]
    assert len(episodes) == EPISODES
    for ep in episodes:
        assert ep["clock"] == "realtime" and ep["rate_hz"] == 20.0
        applied = sum(ep["staleness"].values())
        # every robot-step of the episode: an action applied (at some staleness) or a stay
        assert applied + ep["missed_actions"] == N * ep["length"], ep
        assert applied > 0 and all(int(k) >= 0 for k in ep["staleness"])
        assert ep["stale_actions"] == sum(c for k, c in ep["staleness"].items() if int(k) > 0)
    stopped = next(e for e in events if e["event"] == "stopped")
    total = {k: sum(ep["staleness"].get(k, 0) for ep in episodes)
             for k in stopped["staleness"]}
    assert total == stopped["staleness"]
    # nothing was dropped as out of order by the simulator: late answers are counted, not bad
    assert not {"future_step", "undecodable", "unknown_robot"} & set(stopped["drops"]), stopped


def test_realtime_reaches_the_simulator_and_every_actor() -> None:
    cfg = load_config(Path("configs/launch/deploy-tiny.yaml"),
                      ["clock=realtime", "rate_hz=5", "run_dir=/tmp/unused"])
    nodes = node_parameters(cfg)
    sim = nodes["/sdhn/sim"]
    assert sim["clock"] == "realtime" and sim["rate_hz"] == 5.0
    actors = [v for k, v in nodes.items() if k.endswith("/actor")]
    assert len(actors) == N and all(a["realtime"] for a in actors)
    lockstep = node_parameters(load_config(Path("configs/launch/deploy-tiny.yaml"),
                                           ["run_dir=/tmp/unused"]))
    assert not any(v.get("realtime") for k, v in lockstep.items() if k.endswith("/actor"))
