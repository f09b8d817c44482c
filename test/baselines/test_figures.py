"""make_figures on a small synthetic log directory: every figure and the table are written, and
empty or mixed-up directories are refused with a clear message."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from sdhn_experiments.figures import FigureError, lambda_sk, load_runs, main, make_figures
from sdhn_train.algorithms.mappo import MLPCritic
from sdhn_train.algorithms.sdhn.critic import SDHNCritic
from sdhn_train.config import Config
from sdhn_train.learners.base import HypergraphSamples
from sdhn_train.learners.ppo import Critic
from sdhn_train.rollout import Rollout
from sdhn_train.runs import save_ph_snapshot

METHODS = {"sdhn": {}, "mappo": {}, "qmix": {}, "dicg": {}, "hgcn_mix": {},
           "sdhn_wo_lsk": {"skew_loss": False}, "sdhn_wo_shr": {"stochastic_hyperedges": False}}
ROBOTS = {"maif-10": 10, "maif-16": 16, "rware-3": 3}


def _rollout(n: int, t: int = 3, b: int = 2, d: int = 57) -> Rollout:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(t, b, n, d)).astype(np.float32)
    state = obs.reshape(t, b, -1)
    z = np.zeros((t, b), bool)
    return Rollout(obs, state, np.zeros((t, b, n), np.int64), np.zeros((t, b, n), np.float32),
                   np.zeros((t, b), np.float32), z, z.copy(), obs, state,
                   np.zeros((b, n, 64), np.float32), None)


def _samples(critic: Critic, r: Rollout) -> HypergraphSamples | None:
    with torch.no_grad():
        return critic.hypergraphs(torch.from_numpy(r.obs), critic.initial_state(r.shape[1]),
                                  torch.from_numpy(r.resets()))


def write_run(root: Path, task: str, method: str, seed: int, *, steps: int = 4000,
              completes: bool = True) -> Path:
    run = root / f"{task}__{method}__{seed}"
    run.mkdir(parents=True)
    cfg = Config()
    cfg.env.name, cfg.train.seed, cfg.train.total_steps = task, seed, steps
    cfg.algo.name = "sdhn" if method.startswith("sdhn") else method
    for k, v in METHODS[method].items():
        setattr(cfg.sdhn, k, v)
    (run / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    rng = np.random.default_rng(seed)
    with open(run / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "wall_time", "tag", "value"])
        for step in range(500, steps + 1, 500):
            w.writerow([step, 0, "charts/episodic_return", -50 + step / 100 + rng.normal()])
            if method.startswith("sdhn"):
                w.writerow([step, 0, "hypergraph/skewness", -0.6 * step / steps])
            if step % 1000 == 0:
                w.writerow([step, 0, "eval/episodic_return", -40 + step / 100])
                w.writerow([step, 0, "eval/success_rate", 1.0 if completes else 0.0])
                if completes and task.startswith("maif"):
                    w.writerow([step, 0, "eval/makespan", 200 - step / 100 + 5 * seed])
    if method.startswith("sdhn"):
        n = ROBOTS[task]
        critic = SDHNCritic(57, 57 * n, n, num_hyperedges=5, skew_loss=method != "sdhn_wo_lsk")
        save_ph_snapshot(run, steps, _samples(critic, _rollout(n)))
    return run


@pytest.fixture
def logdir(tmp_path: Path) -> Path:
    torch.manual_seed(0)
    root = tmp_path / "runs"
    for seed in (1, 2):
        for method in METHODS:
            write_run(root, "maif-10", method, seed, completes=method != "qmix")
        for method in ("sdhn", "mappo", "qmix"):
            write_run(root, "maif-16", method, seed, completes=method == "sdhn")
            write_run(root, "rware-3", method, seed)
    return root


def test_every_figure_and_table(logdir: Path, tmp_path: Path) -> None:
    out = tmp_path / "fig"
    written = {p.name for p in make_figures(logdir, out, scripted_instances=4)}
    expected = {"success.png", "returns.png", "makespan.png", "skewness.png",
                "ablation_maif-10.png", "ph_heatmap_maif-10.png", "results.md"}
    assert expected <= written, f"missing {expected - written}; wrote {sorted(written)}"
    for name in expected:
        assert (out / name).stat().st_size > 0, name
    table = (out / "results.md").read_text()
    for label in ("SDHN", "MAPPO", "QMIX", "DICG", "HGCN-MIX", "w/o L_{Sk}", "w/o SHR"):
        assert label in table, f"{label} missing from:\n{table}"
    header = next(line for line in table.splitlines() if line.startswith("| task |"))
    cols = [c.strip() for c in header.strip("|").split("|")]
    # success and makespan come before return, and the return names its reward
    assert cols.index("success") < cols.index("makespan") < cols.index("greedy return (reward)")

    def row(task: str, method: str) -> dict[str, str]:
        line = next(ln for ln in table.splitlines() if ln.startswith(f"| {task} | {method} |"))
        return dict(zip(cols, [c.strip() for c in line.strip("|").split("|")], strict=True))

    qmix = row("maif-10", "QMIX")  # never completed -> NC, not a number
    assert (qmix["makespan"], qmix["held-out makespan"]) == ("NC", "NC"), qmix
    assert qmix["greedy return (reward)"].endswith("(corrected)"), qmix
    assert row("rware-3", "SDHN")["greedy return (reward)"].endswith("(rware)")
    # the scripted baselines are rows of every MAIF task (played here on 4 instances), not RWARE
    for task in ("maif-10", "maif-16"):
        planner = row(task, "scripted planner (centralised)")
        assert float(planner["success"]) == 1.0, planner
        greedy = row(task, "scripted greedy (decentralised)")
        assert greedy["makespan"] == "NC" or float(greedy["makespan"]) >= float(
            planner["makespan"]), (greedy, planner)
    assert "| rware-3 | scripted" not in table


def test_ph_snapshot_only_for_hypergraph_critics(tmp_path: Path) -> None:
    mlp = MLPCritic(57 * 4, 4)
    assert _samples(mlp, _rollout(4)) is None
    assert save_ph_snapshot(tmp_path, 1, None) is None
    critic = SDHNCritic(57, 57 * 4, 4, num_hyperedges=3)
    path = save_ph_snapshot(tmp_path, 7, _samples(critic, _rollout(4)))
    assert path is not None
    with np.load(path) as z:
        assert z["ph_last"].shape == (4, 3) and z["ph_mean"].shape == (4, 3)
        assert float(z["ph_last"].min()) >= 0.0 and float(z["ph_last"].max()) <= 1.0


def test_refuses_empty_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(FigureError, match="is empty"):
        load_runs(tmp_path / "empty")
    assert main([str(tmp_path / "empty"), str(tmp_path / "out")]) == 2
    assert "is empty" in capsys.readouterr().err
    with pytest.raises(FigureError, match="not a directory"):
        load_runs(tmp_path / "missing")


def test_refuses_duplicate_runs(logdir: Path) -> None:
    shutil.copytree(logdir / "maif-10__sdhn__1", logdir / "copy_of_sdhn_1")
    with pytest.raises(FigureError, match="both sdhn on maif-10 with seed 1"):
        load_runs(logdir)


def test_refuses_mixed_budgets(logdir: Path) -> None:
    write_run(logdir, "maif-10", "sdhn", 3, steps=8000)
    with pytest.raises(FigureError, match="mixes budgets on maif-10"):
        load_runs(logdir)


def test_refuses_non_runs(logdir: Path) -> None:
    (logdir / "notes.txt").write_text("hello")
    with pytest.raises(FigureError, match="other files"):
        load_runs(logdir)
    (logdir / "notes.txt").unlink()
    (logdir / "half").mkdir()
    (logdir / "half" / "config.yaml").write_text("{}")
    with pytest.raises(FigureError, match=r"missing metrics\.csv"):
        load_runs(logdir)


def test_skewness_target_comes_from_each_runs_config(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    write_run(root, "maif-10", "sdhn", 1)
    write_run(root, "maif-10", "mappo", 1)
    cfg_file = root / "maif-10__sdhn__1" / "config.yaml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["sdhn"]["lambda_sk"] = 0.25
    cfg_file.write_text(yaml.safe_dump(cfg))
    by_method = {r.method: r for r in load_runs(root)}
    assert lambda_sk(by_method["sdhn"]) == 0.25, "lambda_Sk must be read from the run's config"
    assert "skewness.png" in {p.name for p in make_figures(root, tmp_path / "fig",
                                                           scripted_instances=4)}
