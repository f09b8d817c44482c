"""Transition accounting with real processes (issue 15): sim + 4 actor processes + the trainer node
on maif-tiny, one actor killed mid-run. Every step the simulator made is either a transition the
trainer assembled or a step drop it counted with its cause; the drops are exactly the steps the
killed actor did not answer. The counts come from the trainer's status file (what the launcher
shows), the steps from the simulator's events file."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest

from sdhn_base.drops import DropKind
from sdhn_base.ros.status import EventReader

from .deploy_helpers import actor_cmd, sim_cmd, status_watched_trainer
from .processes import node_processes

N = 4
MAX_STEPS = 30
EPISODES = 4
NS = "/acct"


def test_every_sim_step_is_a_transition_or_a_counted_drop(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    trainer_args, status = status_watched_trainer(tmp_path, monkeypatch, NS)
    events = tmp_path / "sim-events.jsonl"
    actors = [actor_cmd(i, N, ns=NS, seed=i, action_readers=2)  # the simulator, the trainer
              for i in range(N)]
    with node_processes(trainer_args, *actors) as procs:
        trainer, victim = procs[0], procs[N]
        for p in procs:
            assert p.wait_for_line("ready", timeout=60), p.output
        with node_processes(sim_cmd(ns=NS, max_steps=MAX_STEPS, seed=3, episodes=EPISODES,
                                    extra_subscribers=1, step_deadline=0.1,
                                    events_file=str(events))) as (sim,):
            reader = EventReader(events)
            seen: list[dict] = []
            deadline = time.monotonic() + 90
            # kill as soon as episode 0 ends: at full speed the other 90 steps take ~0.2 s
            while not any(e["event"] == "episode" for e in seen):
                assert time.monotonic() < deadline and sim.proc.poll() is None, sim.output
                seen += reader.new()
                time.sleep(0.005)
            victim.proc.send_signal(signal.SIGKILL)
            sim.proc.wait(timeout=120)
            assert sim.proc.returncode == 0, sim.output
        seen += reader.new()
        time.sleep(1.0)  # let the trainer take the last messages
        assert trainer.stop(timeout=20) == 0, trainer.output
    episodes = [e for e in seen if e["event"] == "episode"]
    assert len(episodes) == EPISODES
    steps = sum(int(e["length"]) for e in episodes)
    missed = sum(int(e["missed_actions"]) for e in episodes)  # robot-steps 'stay'ed by the sim
    assert missed > 0, "the kill must cost steps"
    st = json.loads((status / "trainer.status.json").read_text())
    drops = st["dropped"]
    stepped = (DropKind.MISSED_ACTION, DropKind.INCOMPLETE_STEP, DropKind.STEP_NEVER_SEEN)
    step_drops = sum(drops.get(k, 0) for k in stepped)
    print(f"\n{steps} sim steps ({missed} actions missed, the killed actor's): "
          f"{st['transitions']} transitions, drops {drops}, pending {st['pending']}, "
          f"executor lag max {st['executor_lag_max_ms']} ms, learned {st['transitions_learned']}")
    assert st["pending"] == 0
    assert st["transitions"] + step_drops == steps, st
    # a step is lost only when the sim had to 'stay' a robot (the killed actor: one per step)
    assert 0 < step_drops <= missed, "only steps with a missed action may be missing"
    assert set(drops) <= set(stepped), drops
    assert drops.get(DropKind.MISSED_ACTION, 0) > 0, (
        "the sim's missed_actions name the killed actor's steps")
    assert st["transitions_learned"] >= 16, "the learner offload process trained on the rollouts"
    assert "Traceback" not in trainer.output, trainer.output
    assert trainer.output.count("dropped: " + DropKind.MISSED_ACTION) == 1, (
        "each cause is logged once")
