"""The protocol report on a synthetic suite log directory with known answers: SDHN clearly
ahead of MAPPO, level with the 1-layer variant; the verdicts and the marl-eval JSON follow."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

from sdhn_experiments.protocol_report import report

ROOT = Path(__file__).resolve().parents[2]


def _run(logdir: Path, method: str, algo: str, seed: int, *, final: float, ratio: float,
         done: bool = True, task: str = "maif-10") -> None:
    d = logdir / f"{task}__{method}__s{seed}"
    d.mkdir(parents=True)
    cfg = {"env": {"name": task, "reward": "corrected", "max_steps": None},
           "algo": {"name": algo}, "train": {"total_steps": 1000, "seed": seed},
           "sdhn": {}}
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))
    (d / "run.json").write_text(json.dumps({"suite": "synthetic", "method": method,
                                            "task": task, "seed": seed}))
    rows = ["step,wall_time,tag,value"]
    for k, step in enumerate((500, 1000)):
        v = final * (k + 1) / 2
        rows += [f"{step},0,eval/success_rate,{v}", f"{step},0,eval/heldout_success_rate,{v}"]
    (d / "metrics.csv").write_text("\n".join(rows) + "\n")
    n_ok = round(final * 10)
    recs = [{"instance": i, "map": i // 5, "success": i < n_ok, "makespan": 60 if i < n_ok else
             None, "length": 60 if i < n_ok else 500, "wedged": 0, "deadlock": False}
            for i in range(10)]
    (d / "heldout_large.json").write_text(json.dumps(
        {"summary": {"success_rate": final, "makespan_ratio_mean": ratio,
                     "maps_with_zero_success": 0 if final > 0.5 else 1,
                     "failures": {"episodes": 10 - n_ok, "deadlock": 10 - n_ok, "wander": 0}},
         "records": recs}))
    if done:
        (d / "DONE.json").write_text("{}")


def test_report_verdicts_on_known_data(tmp_path: Path) -> None:
    logdir, out = tmp_path / "logs", tmp_path / "out"
    for s in range(1, 6):
        _run(logdir, "sdhn", "sdhn", s, final=0.9 + 0.01 * s, ratio=1.05)
        _run(logdir, "mappo", "mappo", s, final=0.5 + 0.01 * s, ratio=1.5)
        _run(logdir, "sdhn_generator_1_layer", "sdhn", s, final=0.9 + 0.01 * (6 - s), ratio=1.05)
    _run(logdir, "qmix", "qmix", 1, final=0.2, ratio=2.0, done=False)
    written = report(logdir, out, None, compute_absolute=False, reps=200)
    assert {p.name for p in written} >= {"protocol.md", "claims.md", "marl_eval.json",
                                         "sample_efficiency.png"}
    claims = (out / "claims.md").read_text()
    assert "| SDHN outperforms MAPPO on maif-10 | P(SDHN > MAPPO) = 1.00 [1.00, 1.00]" in claims
    assert "| reproduced |" in claims
    # SDHN / MAPPO makespan 0.7 [0.7, 0.7] is below the paper's 0.77: reproduced
    line = next(x for x in claims.splitlines() if "23 %" in x)
    assert "0.700" in line and line.endswith("| reproduced |")
    proto = json.loads((out / "protocol.json").read_text())
    assert proto["unfinished_runs"] == ["maif-10__qmix__s1"]
    # the unfinished run is shown where it stands (its last evaluation, 0.2 at step 1,000)
    assert proto["in_progress"][0]["score"] == 0.2
    assert "| maif-10__qmix__s1 | 0.20 | 1,000 | 1,000 |" in (out / "protocol.md").read_text()
    # MAPPO's seeds complete round(10 * final) of 10: 5, 5, 5, 5 and 6, so 4.8 deadlocks
    mappo_row = next(x for x in (out / "protocol.md").read_text().splitlines()
                     if x.startswith("| MAPPO |"))
    assert "| 4.8, 0.0 | 0.0 |" in mappo_row
    one = proto["tasks"]["maif-10"]["sdhn_generator_1_layer"]["poi_sdhn_over"]
    assert one["point"] == 0.5 and one["ci95_low"] < 0.5 < one["ci95_high"]
    me = json.loads((out / "marl_eval.json").read_text())
    run = me["MAIF"]["maif-10"]["mappo"]["3"]
    assert run["step_1"]["step_count"] == 1000
    assert len(run["absolute_metrics"]["success_rate"]) == 10


def test_report_refuses_an_empty_logdir(tmp_path: Path) -> None:
    (tmp_path / "logs").mkdir()
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "protocol_report.py"),
                          str(tmp_path / "logs"), str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 2 and "protocol_report:" in res.stderr


def _rware_run(logdir: Path, method: str, algo: str, seed: int, *, final: float,
               actor: Path | None = None, absolute: float | None = None) -> Path:
    """A finished RWARE run: eval/deliveries rising to ``final``; the absolute metric cached
    (``absolute``) or left to compute from a real actor file (``actor``)."""
    d = logdir / f"rware-tiny-2ag__{method}__s{seed}"
    d.mkdir(parents=True)
    cfg = {"env": {"name": "rware-tiny-2ag", "max_steps": None}, "algo": {"name": algo},
           "train": {"total_steps": 2000, "seed": seed}, "sdhn": {}}
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))
    (d / "run.json").write_text(json.dumps({"suite": "synthetic", "method": method,
                                            "task": "rware-tiny-2ag", "seed": seed}))
    rows = ["step,wall_time,tag,value"]
    for k, step in enumerate((1000, 2000)):
        rows += [f"{step},0,eval/deliveries,{final * (k + 1) / 2}",
                 f"{step},0,eval/success_rate,0.0"]
    (d / "metrics.csv").write_text("\n".join(rows) + "\n")
    if actor is not None:  # the weights and their checksum sidecar
        for f in (actor, actor.with_suffix(".json")):
            (d / f.name).write_bytes(f.read_bytes())
    if absolute is not None:
        recs = [{"seed": 1_000_000 + i, "deliveries": absolute} for i in range(4)]
        (d / "absolute_deliveries.json").write_text(json.dumps(
            {"summary": {"deliveries_mean": absolute}, "records": recs}))
    (d / "DONE.json").write_text("{}")
    return d


def test_rware_report_pairs_sdhn_with_mappo_at_the_same_settings(tmp_path: Path) -> None:
    """RWARE is judged by deliveries: sdhn_ent01 is compared with mappo_ent01 (same settings),
    a method without an SDHN partner gets no probability of improvement, and the absolute
    metric of a real shipped actor is computed on the cards' episodes and cached."""
    logdir, out = tmp_path / "logs", tmp_path / "out"
    for s in (1, 2, 3):
        _rware_run(logdir, "sdhn_ent01", "sdhn", s, final=30.0 + s, absolute=30.0 + s)
        _rware_run(logdir, "mappo_ent01", "mappo", s, final=10.0 + s, absolute=10.0 + s)
        _rware_run(logdir, "mappo_ff", "mappo", s, final=1.0 * s, absolute=1.0 * s)
    shipped = ROOT / "models" / "rware-tiny-2ag-mappo"
    live = _rware_run(logdir, "mappo_ent01", "mappo", 4, final=23.0,
                      actor=shipped / "actor.safetensors")
    out.mkdir()
    (out / "reference_policies.json").write_text(json.dumps(
        {"rware-tiny-2ag": {"random": 0.0, "scripted": 22.9, "decentralised": 19.1}},
        sort_keys=True))  # as the report writes it: a cache read gives the policies' own order
    report(logdir, out, None, compute_absolute=True, reps=200)

    card = json.loads((shipped / "card.json").read_text())
    computed = json.loads((live / "absolute_deliveries.json").read_text())
    assert computed["summary"]["deliveries_mean"] == card["evaluation"]["policy"]["deliveries_mean"]
    assert len(computed["records"]) == 100

    proto = json.loads((out / "protocol.json").read_text())["tasks"]["rware-tiny-2ag"]
    assert proto["mappo_ent01"]["sdhn_partner"] == "sdhn_ent01"
    assert proto["mappo_ent01"]["poi_sdhn_over"]["point"] == 1.0
    assert proto["mappo_ff"]["poi_sdhn_over"] is None  # no sdhn_ff in the suite
    assert proto["mappo_ff"]["final"] == [1.0, 2.0, 3.0]
    assert proto["reference_policies"]["scripted"] == 22.9
    claims = (out / "claims.md").read_text()
    line = next(x for x in claims.splitlines() if "outperforms MAPPO" in x)
    assert "(both at the `ent01` settings)" in line and line.endswith("| reproduced |")
    assert "MAPPO (ff)" not in claims
    md = (out / "protocol.md").read_text()
    assert "random 0.0, scripted 22.9, decentralised 19.1." in md and "MAPPO (ent01)" in md
    me = json.loads((out / "marl_eval.json").read_text())
    run = me["RWARE"]["rware-tiny-2ag"]["mappo_ent01"]["4"]
    assert run["step_1"] == {"step_count": 2000, "deliveries": [23.0]}
    assert len(run["absolute_metrics"]["deliveries"]) == 100


def test_pairs_and_labels() -> None:
    from sdhn_experiments.protocol_report import label, sdhn_partner

    methods = {"sdhn", "sdhn_ent01", "mappo", "mappo_ent01", "mappo_ff", "hgcn_mix",
               "sdhn_wo_lsk"}
    assert sdhn_partner("mappo", methods) == "sdhn"
    assert sdhn_partner("mappo_ent01", methods) == "sdhn_ent01"
    assert sdhn_partner("mappo_ff", methods) is None
    assert sdhn_partner("hgcn_mix", methods) == "sdhn"  # not read as hgcn + "_mix"
    assert sdhn_partner("sdhn_wo_lsk", methods) == "sdhn"
    assert sdhn_partner("sdhn", methods) is None
    assert label("mappo_ff_ent01") == "MAPPO (ff_ent01)"
    assert label("sdhn_wo_lsk") == "SDHN w/o L_Sk"


def test_too_few_seeds_give_no_verdict(tmp_path: Path) -> None:
    """One seed against one: SDHN scores below MAPPO, but a single pair is no evidence, so the
    claim stays inconclusive however far apart the two runs are."""
    logdir, out = tmp_path / "logs", tmp_path / "out"
    _run(logdir, "sdhn", "sdhn", 1, final=0.5, ratio=1.2)
    _run(logdir, "mappo", "mappo", 1, final=0.9, ratio=1.0)
    report(logdir, out, None, compute_absolute=False, reps=200)
    claims = (out / "claims.md").read_text()
    rows = [x for x in claims.splitlines() if x.startswith("| SDHN")]
    assert len(rows) == 2 and all(r.endswith("| inconclusive: 1 seed (a verdict needs 3) |")
                                  for r in rows)
    assert "| 0.00 (1 vs 1 seed) |" in (out / "protocol.md").read_text()


def test_scaling_failure_claim(tmp_path: Path) -> None:
    """'MAPPO fails on maif-16': one seed gives its bare score and no verdict; three seeds that
    all complete 0.9 contradict it (the interval lies above 0.5)."""
    logdir, out = tmp_path / "logs", tmp_path / "out"
    _run(logdir, "mappo", "mappo", 1, final=0.9, ratio=1.0, task="maif-16")
    report(logdir, out, None, compute_absolute=False, reps=200)
    row = next(x for x in (out / "claims.md").read_text().splitlines() if "fails on" in x)
    assert "MAPPO mean absolute success 0.90 |" in row
    assert row.endswith("| inconclusive: 1 seed (a verdict needs 3) |")
    for s in (2, 3):
        _run(logdir, "mappo", "mappo", s, final=0.9, ratio=1.0, task="maif-16")
    report(logdir, out, None, compute_absolute=False, reps=200)
    row = next(x for x in (out / "claims.md").read_text().splitlines() if "fails on" in x)
    assert row.endswith("| contradicted |")
