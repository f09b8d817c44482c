"""Train mode with real processes: sim + 4 actor processes + trainer + recorder on maif-tiny. The
trainer publishes version 1 at start and new versions after updates; the actors switch (their
actions carry the new versions); the recorder's MCAP holds every step of every finished episode,
and replay's summary recomputed from the recorded state equals the simulator's."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from sdhn_sim.recording.reader import read_recording, summaries_from_messages, summaries_from_states
from sdhn_train.checkpoint import latest_checkpoint

from .deploy_helpers import TEAM_NS, Seen, actor_cmd, observer, sim_cmd, trainer_cmd
from .processes import ROS2, NodeProcess, node_processes

N = 4
MAX_STEPS = 16
ROLLOUT = 16


@dataclass
class TrainRun:
    seen: Seen
    trainer: NodeProcess
    recording: Path
    run_dir: Path
    seconds: float


def tiny_trainer(run_dir: Path, config: Path, resume: bool = False) -> list[str]:
    return trainer_cmd(run_dir, config, rollout_steps=ROLLOUT, resume=resume)


@pytest.fixture(scope="module")
def train_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TrainRun]:
    tmp = tmp_path_factory.mktemp("train")
    config = tmp / "trainer.yaml"
    config.write_text("ppo:\n  epochs: 2\nlog:\n  tensorboard: false\n")
    run_dir, recording = tmp / "run", tmp / "run.mcap"
    trainer = tiny_trainer(run_dir, config)
    recorder = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={recording}"]
    # no weights_file: wait for the trainer; action readers: the simulator, the trainer, the
    # recorder and the observer
    actors = [actor_cmd(i, N, seed=i, action_readers=4) for i in range(N)]
    with observer(N) as (_node, seen, spin), \
            node_processes(trainer, recorder, *actors) as procs:
        for p in procs:
            assert p.wait_for_line("ready", timeout=40), p.output
        t0 = time.monotonic()
        with node_processes(sim_cmd(max_steps=MAX_STEPS, seed=5, extra_subscribers=3,
                                    step_deadline=2.0)) as (sim,):

            def switched() -> bool:
                return any(v >= 3 for _a, v in seen.actions.values())

            ok = spin(45, switched)
            seconds = time.monotonic() - t0
            # The observer takes messages only while it spins, and the actors can switch within
            # a second of step 0: go on taking them until both once-a-second reports the
            # diagnostics test checks are in (it once saw the recorder's and the actors' but no
            # trainer's, twice in a row, in a full run on 7 Dec 2026; not reproduced since).
            spin(10, lambda: {"/trainer", "/recorder"} <= seen.diagnostics.keys())
            sim.stop()
            assert ok, (f"actors never used version >= 3; versions seen "
                        f"{sorted({v for _a, v in seen.actions.values()})}\n--- trainer\n"
                        f"{procs[0].output}\n--- sim\n{sim.output[-3000:]}")
        for p in procs:
            assert p.stop(timeout=8) == 0, p.output
        yield TrainRun(seen, procs[0], recording, run_dir, seconds)


def test_trainer_publishes_new_versions_and_actors_switch(train_run: TrainRun) -> None:
    versions = {v for _a, v in train_run.seen.actions.values()}
    assert min(versions) == 1, "actors begin with the trainer's version 1"
    assert max(versions) >= 3, f"two new versions reached the actors: {sorted(versions)}"
    out = train_run.trainer.output
    updates = [line for line in out.splitlines() if "update: version=" in line]
    assert len(updates) >= 2, out
    sizes = {int(m) for m in re.findall(r"weights_bytes=(\d+)", out)}
    update_s = [float(m) for m in re.findall(r"update_s=([0-9.]+)", out)]
    publish_ms = [float(m) for m in re.findall(r"publish_ms=([0-9.]+)", out)]
    print(f"\n{len(updates)} updates in {train_run.seconds:.1f} s; update_s "
          f"{min(update_s):.3f}-{max(update_s):.3f}; weights {sizes} bytes, publish "
          f"{min(publish_ms):.1f}-{max(publish_ms):.1f} ms\n" + "\n".join(updates[:3]) + "\n"
          + "\n".join(line for line in out.splitlines() if "status:" in line)[-600:])
    # checkpoints: the newest one is the newest published version
    last = max(int(m) for m in re.findall(r"update: version=(\d+)", out))
    newest = latest_checkpoint(train_run.run_dir)
    assert newest is not None
    assert json.loads(newest.with_suffix(".json").read_text())["version"] == last
    assert "Traceback" not in out


def test_trainer_and_recorder_report_on_diagnostics(train_run: TrainRun) -> None:
    """The trainer's and the recorder's /diagnostics (docs/lifecycle-and-diagnostics.md): queue
    depth, drops by cause and the weights version; write queue and messages written."""
    reports = train_run.seen.diagnostics
    want = {"/trainer": {"weights_version", "queue_depth", "transitions", "dropped_in_window"},
            "/recorder": {"write_queue_depth", "not_written", "messages_written",
                          "dropped_in_window"}}
    for name, keys in want.items():
        assert name in reports, sorted(reports)
        last = {kv.key: kv.value for kv in reports[name][-1].values}
        assert keys <= set(last), (name, keys - set(last))
    versions = [int({kv.key: kv.value for kv in s.values}["weights_version"])
                for s in reports["/trainer"]]
    # the versions it reports are the ones it publishes: rising, as the actors used them
    used = {v for _a, v in train_run.seen.actions.values()}
    assert versions == sorted(versions) and versions[0] >= 1 and versions[-1] <= max(used), (
        versions, sorted(used))


def test_resume_continues_from_the_last_version(train_run: TrainRun, tmp_path: Path) -> None:
    out = train_run.trainer.output
    last = max(int(m) for m in re.findall(r"update: version=(\d+)", out))
    newest = latest_checkpoint(train_run.run_dir)
    assert newest is not None
    config = tmp_path / "trainer.yaml"
    config.write_text("log:\n  tensorboard: false\n")
    with node_processes(tiny_trainer(train_run.run_dir, config, resume=True)) as (trainer,):
        assert trainer.wait_for_line("ready", timeout=40), trainer.output
        assert trainer.stop(timeout=8) == 0, trainer.output
    assert f"version={last} (resumed from {newest.name})" in trainer.output, trainer.output


def test_recording_of_the_train_run_holds_every_step(train_run: TrainRun) -> None:
    rec = read_recording(train_run.recording)
    assert rec.truncated is None
    live = summaries_from_messages(rec)
    assert live, "no finished episode was recorded"
    recomputed = summaries_from_states(rec)
    obs: dict[tuple[int, int], int] = {}
    for raw in rec.messages:
        if raw.topic.endswith("/obs"):
            from sdhn_sim.recording.reader import decode

            m = decode(raw)
            obs[(m.episode, m.step)] = obs.get((m.episode, m.step), 0) + 1
    acts = {(e, s) for (e, s, _r) in train_run.seen.actions}
    actions: dict[tuple[int, int], int] = {}
    for _, a in rec.decoded("/action"):
        actions[(a.episode, a.step)] = actions.get((a.episode, a.step), 0) + 1
    states = {(s.episode, s.step) for _, s in rec.decoded("/state")}
    def recorded(count: int | None, k: int, t: int) -> bool:
        # The first step of the run may hold re-sent copies: until every robot has answered it,
        # the simulator re-sends it to the silent ones (its start handshake), who answer each.
        return count == N or (k == 0 and t == 0 and count is not None and count > N)

    for k, row in live.items():
        for t in range(row.length + 1):
            assert recorded(obs.get((k, t)), k, t), f"episode {k} step {t}: {obs.get((k, t))} obs"
            assert (k, t) in states, f"episode {k} step {t}: no state recorded"
        for t in range(row.length):
            assert recorded(actions.get((k, t)), k, t), (
                f"episode {k} step {t}: {actions.get((k, t))} actions")
            assert (k, t) in acts
        b = recomputed[k]
        assert (row.length, row.completed, row.makespan, row.missed_actions, row.policy_version
                ) == (b.length, b.completed, b.makespan, b.missed_actions, b.policy_version)
        assert b.episode_return == pytest.approx(row.episode_return, rel=1e-5, abs=1e-4)
    weights = [m for m in rec.messages if m.topic == f"{TEAM_NS}/policy/weights"]
    assert len(weights) >= 3, "versions 1 (latched) and at least two updates"
    assert any(m.topic == f"{TEAM_NS}/hypergraph" for m in rec.messages)
