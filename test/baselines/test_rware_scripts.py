"""The RWARE evaluation tools (sdhn_experiments.rware_baseline_eval, .rware_policy_eval) on both
backends, the learning-curve plot's baseline lines (.curves) and learning onset."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import pytest
import yaml

from sdhn_experiments import curves, learning_onset, rware_baseline_eval, rware_policy_eval
from sdhn_train.config import Config

REPO = Path(__file__).resolve().parents[2]


def test_eval_rware_baselines_prints_every_policy(capsys):
    assert rware_baseline_eval.main(["rware-3", "--episodes", "1", "--seed", "2", "--json"]) == 0
    rows = {r["policy"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert set(rows) == {"random", "scripted", "decentralised"}, rows
    for r in rows.values():
        assert r["deliveries_mean"] == r["return_mean"] and r["seeds"] == "2..2", r
        assert "rware" in r["reward"], r
    assert rows["scripted"]["deliveries_mean"] >= 15 > rows["random"]["deliveries_mean"], rows
    assert rows["decentralised"]["deliveries_mean"] >= 5, rows


def test_eval_rware_baselines_refuses_an_unknown_policy(capsys):
    assert rware_baseline_eval.main(["rware-3", "--policies", "random,greedy"]) == 2
    err = capsys.readouterr().err
    assert "--policies" in err and "greedy" in err and "decentralised" in err, err


def test_plot_curves_draws_baselines(tmp_path):
    run = tmp_path / "rware-3__sdhn__1"
    run.mkdir()
    with open(run / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "wall_time", "tag", "value"])
        for step in range(0, 5000, 1000):
            w.writerow([step, 0, "eval/episodic_return", step / 1000])
    out = tmp_path / "curves.png"
    assert curves.main([str(run), "--tags", "eval/episodic_return", "--hline",
                             "scripted (centralised)=29.9", "--hline", "random=0.1",
                             "--titles", "greedy deliveries", "--symlog", "--out", str(out)]) == 0
    assert out.stat().st_size > 1000
    drawn = curves.plot([run], ["eval/episodic_return", "charts/none"], out,
                             hlines=[("scripted", 29.9), ("random", 0.1)])
    assert drawn == {"eval/episodic_return": ["rware-3__sdhn (n=1)", "scripted: 29.9",
                                              "random: 0.1"],
                     "charts/none": ["scripted: 29.9", "random: 0.1"]}, drawn
    drawn = curves.plot([run], ["eval/episodic_return"], out, per_run=True)
    assert drawn == {"eval/episodic_return": ["rware-3__sdhn__1 (n=1)"]}, drawn
    assert curves.parse_hline("a=b=2.5") == ("a=b", 2.5)
    for bad in ("random", "=1", "random=x"):
        with pytest.raises(argparse.ArgumentTypeError):
            curves.parse_hline(bad)
    with pytest.raises(SystemExit):
        curves.main([str(run), "--tags", "eval/episodic_return", "--titles", "a", "b"])


def test_eval_rware_policy_plays_its_own_and_a_larger_team(capsys):
    """The shipped rware-3 actor on its own team and zero-shot on rware-6 (ids widened): both
    deliver (a broken id widening or runtime gives 0), and the rows say which is zero-shot."""
    assert rware_policy_eval.main([str(REPO / "models/rware-3-mappo"), "rware-3", "rware-6",
                          "--episodes", "2", "--json"]) == 0
    rows = {r["task"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert rows["rware-3"]["trained_robots"] == rows["rware-6"]["trained_robots"] == 3, rows
    assert rows["rware-6"]["robots"] == 6 and rows["rware-6"]["episodes"] == 2, rows
    assert rows["rware-3"]["deliveries_mean"] >= 5 and rows["rware-6"]["deliveries_mean"] >= 5


def test_eval_rware_policy_refuses_a_maif_actor_and_a_missing_file(capsys, tmp_path):
    assert rware_policy_eval.main([str(REPO / "models/maif-10-sdhn"), "rware-3"]) == 2
    assert "57-float" in capsys.readouterr().err
    assert rware_policy_eval.main([str(tmp_path / "none"), "rware-3"]) == 2
    assert "no such actor file" in capsys.readouterr().err


def _onset_run(root: Path, name: str, deliveries: list[float], entropy: list[float]) -> None:
    run = root / name
    run.mkdir(parents=True)
    cfg = Config()
    cfg.env.name = "rware-3"
    (run / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    with open(run / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "wall_time", "tag", "value"])
        for i, (d, e) in enumerate(zip(deliveries, entropy, strict=True)):
            w.writerow([(i + 1) * 250_000, 0, "eval/deliveries", d])
            w.writerow([(i + 1) * 250_000, 0, "losses/entropy", e])


def test_learning_onset_names_the_first_steps_and_the_runs_that_never_learned(tmp_path, capsys):
    _onset_run(tmp_path, "rware-3__a_warm__s1", [0, 0, 0.5, 4, 12], [0.1, 0.2, 0.6, 0.9, 0.5])
    _onset_run(tmp_path, "rware-3__a_warm__s2", [0, 0, 0, 0, 0], [0.1, 0.1, 0.1, 0.2, 0.1])
    _onset_run(tmp_path, "rware-3__b__s1", [9, 9, 9, 9, 9], [1, 1, 1, 1, 1])
    assert learning_onset.main([str(tmp_path), "--match", "_warm", "--level", "10",
                                "--at", "1e6"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| rware")]
    assert rows == ["| rware-3__a_warm__s1 | 0.75 M | 1.25 M | 4.0 | 12.0 | 0.10 | 0.90 |",
                    "| rware-3__a_warm__s2 | not by 1.25 M | not by 1.25 M | 0.0 | 0.0 | 0.10 | "
                    "0.20 |"]
    assert learning_onset.main([str(tmp_path), "--match", "nothing"]) == 1
