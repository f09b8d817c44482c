"""make_figures on damaged logs and bad arguments: every case is one line and exit 2 (or, for the
scripted baselines' cache, a recomputation), never a traceback."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from sdhn_experiments.figures import main
from sdhn_train.config import Config

from .errors import one_line


def write_run(root: Path, task: str = "rware-3", method: str = "mappo", seed: int = 1) -> Path:
    run = root / f"{task}__{method}__s{seed}"
    run.mkdir(parents=True)
    cfg = Config()
    cfg.env.name, cfg.algo.name, cfg.train.seed = task, method, seed
    cfg.eval.instances = 1
    (run / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    with open(run / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "wall_time", "tag", "value"])
        for step in (500, 1000):
            w.writerow([step, 0, "charts/episodic_return", step / 100])
            w.writerow([step, 0, "eval/episodic_return", step / 50])
            w.writerow([step, 0, "eval/success_rate", 0.5])
    return run


def figures(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str]:
    rc = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err


METRICS = {
    "binary": (bytes(range(256)) * 8, "not a text file"),
    "non-numeric-row": (b"step,wall_time,tag,value\n500,0,a,1\nfive,0,a,2\n1000,0,a,3\n",
                        "line 3"),
    "non-numeric-value": (b"step,wall_time,tag,value\n500,0,a,lots\n1000,0,a,3\n", "line 2"),
    "short-row-midway": (b"step,wall_time,tag,value\n500,0\n1000,0,a,3\n", "line 2"),
    "no-header": (b"500,0,a,1\n", "not a trainer metrics.csv"),
}


@pytest.mark.parametrize("case", list(METRICS))
def test_damaged_metrics_are_one_line(case: str, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    data, expected = METRICS[case]
    run = write_run(tmp_path / "logs")
    (run / "metrics.csv").write_bytes(data)
    rc, err = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 2 and expected in one_line(err) and "metrics.csv" in err


def test_a_cut_off_last_row_is_left_out(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    run = write_run(tmp_path / "logs")
    with open(run / "metrics.csv", "a") as f:
        f.write("1500,0,charts/episodic_ret")  # a crash mid-write
    rc, _ = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 0
    assert "| rware-3 | MAPPO | 1 | 1000 |" in (tmp_path / "out" / "results.md").read_text()


@pytest.mark.parametrize("content", ["step,wall_time,tag,value\n", ""],
                         ids=["header-only", "empty"])
def test_a_run_with_nothing_logged_yet_is_a_row_without_numbers(
        content: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What a suite's log directory holds while a run has just started (the report is run
    beside a running suite)."""
    write_run(tmp_path / "logs")
    empty = write_run(tmp_path / "logs", method="qmix")
    (empty / "metrics.csv").write_text(content)
    rc, _ = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 0
    assert "| rware-3 | QMIX | 1 | 0 |" in (tmp_path / "out" / "results.md").read_text()


def test_a_run_directory_just_created_by_the_runner_is_left_out(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The runner writes run.json before its trainer writes config.yaml and metrics.csv."""
    write_run(tmp_path / "logs")
    starting = tmp_path / "logs" / "rware-3__qmix__s1"
    starting.mkdir()
    (starting / "run.json").write_text(json.dumps({"task": "rware-3", "method": "qmix",
                                                   "seed": 1}))
    rc, _ = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 0
    assert "QMIX" not in (tmp_path / "out" / "results.md").read_text()


CONFIGS = {
    "garbage": (b"env: {name: [\n", "malformed YAML"),
    "binary": (bytes(range(256)), "not a text file"),
    "list": (b"- env\n- algo\n", "not a trainer config"),
    "no-env": (b"algo: {name: mappo}\ntrain: {seed: 1}\n", "not a trainer config"),
    "duplicate": (b"env: {name: rware-3}\nenv: {name: maif-10}\n", "duplicate key 'env'"),
}


@pytest.mark.parametrize("case", list(CONFIGS))
def test_damaged_config_is_one_line(case: str, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    data, expected = CONFIGS[case]
    run = write_run(tmp_path / "logs")
    (run / "config.yaml").write_bytes(data)
    rc, err = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 2 and expected in one_line(err)


@pytest.mark.parametrize("data", [b"", b"{", b"[1]", b'{"task": "maif-nope"}'],
                         ids=["empty", "garbage", "list", "unknown-task"])
def test_damaged_run_json_is_one_line(data: bytes, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    run = write_run(tmp_path / "logs")
    (run / "run.json").write_bytes(data)
    rc, err = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 2 and ("run.json" in one_line(err) or "maif-nope" in err)


@pytest.mark.parametrize("data", [b"garbage", b"PK\x03\x04broken"], ids=["text", "bad-zip"])
def test_damaged_ph_snapshot_is_one_line(data: bytes, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The newest P_H snapshot of an SDHN run is damaged (both runs the heatmap compares have
    one)."""
    runs = []
    for seed, skew_loss in ((1, True), (2, False)):
        run = write_run(tmp_path / "logs", method="sdhn", seed=seed)
        cfg = yaml.safe_load((run / "config.yaml").read_text())
        cfg["sdhn"]["skew_loss"] = skew_loss
        (run / "config.yaml").write_text(yaml.safe_dump(cfg))
        (run / "hypergraph").mkdir()
        np.savez(run / "hypergraph" / "ph_000000001000.npz", step=np.int64(1000),
                 ph_last=np.full((3, 2), 0.5), ph_mean=np.full((3, 2), 0.5))
        runs.append(run)
    (runs[0] / "hypergraph" / "ph_000000002000.npz").write_bytes(data)
    rc, err = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 2 and "ph_000000002000.npz" in one_line(err)


def test_output_that_is_a_file_and_bad_instances(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    write_run(tmp_path / "logs")
    (tmp_path / "out").write_text("a file")
    rc, err = figures(capsys, tmp_path / "logs", tmp_path / "out")
    assert rc == 2 and "not a directory" in one_line(err)
    assert (tmp_path / "out").read_text() == "a file"
    for k in ("-3", "0"):
        rc, err = figures(capsys, tmp_path / "logs", tmp_path / "fig", "--scripted-instances", k)
        assert rc == 2 and "--scripted-instances" in one_line(err)
    assert not (tmp_path / "fig").exists()


# The cache key of the scripted greedy policy on the run below (task/set/policy/k/seed/reward).
KEY = f"maif-solo/train/greedy/k=1/seed={Config().eval.seed}/{Config().env.reward}"


WRONG_TYPES = {"task": "maif-solo", "instance_set": "train", "policy": "greedy",
               "success_rate": "x", "makespan": None, "lower_bound": 1, "episode_return": 0,
               "reward": "corrected", "collisions": 0}


@pytest.mark.parametrize("cache", [b"{garbage", b"[1, 2]",
                                   json.dumps({KEY: {"task": 1}}).encode(),
                                   json.dumps({KEY: WRONG_TYPES}).encode(),
                                   bytes(range(256))],
                         ids=["garbage", "list", "wrong-fields", "wrong-types", "binary"])
def test_damaged_scripted_cache_is_recomputed(cache: bytes, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    write_run(tmp_path / "logs", task="maif-solo")
    out = tmp_path / "out"
    out.mkdir()
    (out / "scripted.json").write_bytes(cache)
    rc, err = figures(capsys, tmp_path / "logs", out, "--scripted-instances", "1")
    assert rc == 0, err
    known = json.loads((out / "scripted.json").read_text())
    assert isinstance(known[KEY]["success_rate"], float), known
