"""Carrying a suite's log directory to another machine (sdhn_experiments/carry.py): a finished
run is skipped there, an unfinished one resumes from its carried checkpoint in a log directory at
another path and ends with the same results as an uninterrupted run, and a restore never
replaces newer progress. The carried form is compact (logs packed, no checkpoint, snapshot or
actor a finished run's reports do not read) and the reports read it as they read a log
directory."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from sdhn_experiments.carry import MANIFEST, main, progress, restore, save
from sdhn_experiments.experiments import DONE, load_suite, prepare, run_suite
from sdhn_experiments.figures import read_run
from sdhn_experiments.protocol_report import absolute_records
from sdhn_train.checkpoint import checkpoints

from .run_rows import metric_rows
from .test_experiments import RESUME_SUITE

# test_experiments' resume suite (its budget leaves several checkpoints per run), with two PPO
# methods: the value-mixing runs would only make this slower.
SUITE = yaml.safe_dump({**yaml.safe_load(RESUME_SUITE), "name": "carry",
                        "methods": {"sdhn": {"algo": "sdhn"}, "mappo": {"algo": "mappo"}}},
                       sort_keys=False)


def test_carry_skips_finished_and_resumes_unfinished_elsewhere(tmp_path: Path) -> None:
    suite = tmp_path / "carry.yaml"
    suite.write_text(SUITE)
    runs = load_suite(suite, "quick")
    first, second = (r.name for r in runs)
    machine_a = tmp_path / "a" / "logs"
    assert run_suite(runs[:1], machine_a, jobs=1, out=io.StringIO())["done"] == 1
    # The second run trained by the runner's own command but never finished by it (which
    # would prune its checkpoints to the newest), as if the machine went away at the end ...
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    subprocess.run(prepare(runs[1], machine_a), env=env, check=True, capture_output=True)
    reference = metric_rows(machine_a / second)

    # ... and then rolled back to an earlier checkpoint: no marker, midway.
    assert not (machine_a / second / DONE).exists()
    ckpts = checkpoints(machine_a / second)
    assert len(ckpts) >= 2, "the budget should leave more than one checkpoint"
    for stem in ckpts[1:]:
        stem.with_suffix(".json").unlink()
        stem.with_suffix(".safetensors").unlink()
    step = progress(machine_a / second).step
    assert 0 < step < 768

    carried = tmp_path / "repo" / "carry" / "carry-quick"
    lines = save(machine_a, carried)
    assert any(second in x and f"step {step:,}" in x for x in lines), lines
    assert not list(carried.rglob("events.out.tfevents*"))
    assert not (carried / first / "checkpoints").exists()  # a finished run needs none
    assert sorted(p.name for p in (carried / second / "checkpoints").iterdir()) == [
        f"{ckpts[0].name}.json", f"{ckpts[0].name}.safetensors"]  # the newest one only
    assert (carried / MANIFEST).is_file()

    machine_b = tmp_path / "b" / "elsewhere"  # another path: the saved log root differs
    assert main(["restore", str(carried), str(machine_b)]) == 0
    out = io.StringIO()
    counts = run_suite(runs, machine_b, jobs=1, out=out)
    assert counts == {"done": 1, "skipped": 1, "failed": 0}, out.getvalue()
    assert metric_rows(machine_b / second) == reference

    # Restoring the older carried copy again keeps the finished run.
    again = restore(carried, machine_b)
    assert all("kept" in x for x in again), again
    assert (machine_b / second / DONE).is_file()


def test_carry_refuses_a_missing_log_directory(tmp_path: Path) -> None:
    assert main(["save", str(tmp_path / "nope"), str(tmp_path / "dest")]) == 2


def test_carry_leaves_out_a_checkpoint_too_large_to_carry_whole(tmp_path: Path) -> None:
    # A QMIX checkpoint holds its replay buffer (1.3 GB): its weights stay behind, so its JSON
    # half must too, and the run is carried as one that starts again.
    logdir = tmp_path / "logs"
    run = logdir / "maif-tiny__qmix__s1"
    (run / "checkpoints").mkdir(parents=True)
    (run / "run.json").write_text("{}")
    (run / "metrics.csv").write_text("step\n")
    stem = run / "checkpoints" / "step_000000001024"
    stem.with_suffix(".json").write_text("{}")
    stem.with_suffix(".safetensors").write_bytes(b"\0" * 4096)
    assert progress(run).step == 1024

    carried = tmp_path / "carry"
    lines = save(logdir, carried, max_file_bytes=1000)
    assert lines[0].startswith(f"{run.name}: no checkpoint"), lines
    assert any("starts again from scratch" in x for x in lines), lines
    assert not (carried / run.name / "checkpoints").exists()
    assert (carried / run.name / "metrics.csv.xz").is_file()
    assert '"no checkpoint"' in (carried / MANIFEST).read_text()

    # Under the limit the pair goes together.
    save(logdir, carried, max_file_bytes=10_000)
    assert progress(carried / run.name).step == 1024


def test_carry_manifest_keeps_earlier_runs_but_forgets_removed_copies(tmp_path: Path) -> None:
    # A run carried earlier from another log directory stays listed; one whose carried copy was
    # deleted (a run abandoned rather than carried on) must not stay in the manifest.
    def make_run(logdir: Path, name: str) -> None:
        run = logdir / name
        run.mkdir(parents=True)
        (run / "run.json").write_text("{}")
        (run / "metrics.csv").write_text("step\n")

    carried = tmp_path / "carry"
    make_run(tmp_path / "first", "maif-tiny__sdhn__s1")
    make_run(tmp_path / "first", "maif-tiny__qmix__s2")
    save(tmp_path / "first", carried)
    shutil.rmtree(carried / "maif-tiny__qmix__s2")

    make_run(tmp_path / "second", "maif-tiny__mappo__s1")
    save(tmp_path / "second", carried)
    listed = json.loads((carried / MANIFEST).read_text())["runs"]
    assert sorted(listed) == ["maif-tiny__mappo__s1", "maif-tiny__sdhn__s1"]


def test_a_finished_run_is_carried_compact_and_read_as_it_is(tmp_path: Path) -> None:
    suite = tmp_path / "carry.yaml"
    suite.write_text(SUITE)
    run = load_suite(suite, "quick")[0]  # SDHN: it writes P_H snapshots
    logdir = tmp_path / "logs"
    assert run_suite([run], logdir, jobs=1, out=io.StringIO())["done"] == 1
    d = logdir / run.name
    snaps = sorted((d / "hypergraph").glob("ph_*.npz"))
    assert len(snaps) >= 2, "the budget should leave several snapshots"
    # The absolute metric as protocol_report caches it (a few records; the real one is 1,000).
    (d / "heldout_large.json").write_text(json.dumps(
        {"set": "heldout_large", "records": [{"success": 1, "length": 40},
                                             {"success": 0, "length": 80}]}))
    # A leftover checkpoint of a finished run (the runner prunes to the newest; carry drops all).
    (d / "checkpoints").mkdir(exist_ok=True)
    (d / "checkpoints" / "step_000000000001.json").write_text("{}")

    carried = tmp_path / "carry" / "carry-quick"
    save(logdir, carried)
    c = carried / run.name
    assert (c / "metrics.csv.xz").is_file() and not (c / "metrics.csv").exists()
    assert (c / "train.log.xz").is_file() and (c / "heldout_large.json.xz").is_file()
    assert not (c / "actor.safetensors").exists()  # its absolute metric is cached
    assert not (c / "checkpoints").exists()
    assert [p.name for p in (c / "hypergraph").iterdir()] == [snaps[-1].name]
    assert (c / "metrics.csv.xz").stat().st_size < (d / "metrics.csv").stat().st_size / 4

    # A report reads the carried copy as it reads the log directory.
    here, there = read_run(d), read_run(c)
    assert here.series.keys() == there.series.keys() and here.series
    for tag, (steps, values) in here.series.items():
        assert (there.series[tag][0] == steps).all() and (there.series[tag][1] == values).all()
    assert absolute_records(there) == absolute_records(here) == {
        "success_rate": [1.0, 0.0], "episode_length": [40.0, 80.0]}

    # Restored, the logs are the trainer's own bytes again.
    back = tmp_path / "back"
    restore(carried, back)
    for name in ("metrics.csv", "train.log", "heldout_large.json", "run.json", "config.yaml"):
        assert (back / run.name / name).read_bytes() == (d / name).read_bytes(), name
    assert not list((back / run.name).glob("*.xz"))


def test_a_finished_run_keeps_its_actor_until_its_absolute_metric_is_cached(
        tmp_path: Path) -> None:
    logdir = tmp_path / "logs"
    run = logdir / "maif-tiny__sdhn__s1"
    run.mkdir(parents=True)
    for name in ("run.json", "DONE.json", "actor.json"):
        (run / name).write_text("{}")
    (run / "actor.safetensors").write_bytes(b"\0" * 64)
    (run / "metrics.csv").write_text("step,wall_time,tag,value\n")
    save(logdir, tmp_path / "carried")
    assert (tmp_path / "carried" / run.name / "actor.safetensors").is_file()


def test_a_run_judged_at_several_budgets_keeps_its_actor_until_each_mode_is_cached(
        tmp_path: Path) -> None:
    """The protocol's greedy cache alone is not enough for a run with marked actors: its final
    actor is still needed for the deployed mode (budget_marks)."""
    logdir = tmp_path / "logs"
    run = logdir / "maif-10__sdhn__s1"
    (run / "actors").mkdir(parents=True)
    for name in ("run.json", "DONE.json", "actor.json", "heldout_large.json"):
        (run / name).write_text("{}")
    (run / "config.yaml").write_text(yaml.safe_dump({"train": {"total_steps": 4096}}))
    (run / "actor.safetensors").write_bytes(b"\0" * 64)
    (run / "metrics.csv").write_text("step,wall_time,tag,value\n")
    save(logdir, tmp_path / "carried")
    assert (tmp_path / "carried" / run.name / "actor.safetensors").is_file()
    (run / "actors" / "step_4096.deployed.json").write_text("{}")
    save(logdir, tmp_path / "again")
    assert not (tmp_path / "again" / run.name / "actor.safetensors").exists()
    assert (tmp_path / "again" / run.name / "actors" / "step_4096.deployed.json").is_file()


def test_carry_refuses_a_destination_that_overlaps_the_source(tmp_path: Path) -> None:
    """Issue 54 item 8: ``save LOGDIR LOGDIR`` replaced every run by its trimmed copy
    (TensorBoard events, checkpoints, dotfiles gone), exit 0."""
    logdir = tmp_path / "logs"
    run = logdir / "maif-tiny__sdhn__s1"
    run.mkdir(parents=True)
    (run / "run.json").write_text("{}")
    (run / "metrics.csv").write_text("step\n")
    (run / "events.out.tfevents.1").write_bytes(b"tb")
    (run / ".hidden").write_text("x")
    (tmp_path / "link").symlink_to(logdir)
    for cmd, a, b in (("save", logdir, logdir), ("save", logdir, logdir / "carry"),
                      ("save", logdir / "maif-tiny__sdhn__s1", logdir),
                      ("save", logdir, tmp_path / "link"), ("restore", logdir, logdir),
                      ("restore", logdir, logdir / "sub")):
        assert main([cmd, str(a), str(b)]) == 2, (cmd, a, b)
    assert sorted(p.name for p in run.iterdir()) == [
        ".hidden", "events.out.tfevents.1", "metrics.csv", "run.json"]
    assert not (logdir / "carry").exists() and not (logdir / "sub").exists()
