"""One run judged at several budgets: the actors exported at ``log.actor_marks`` evaluated on
the large held-out set (greedy and the shipped card's mode), cached beside each actor, counted
for unfinished runs, and compared per mark in the protocol report."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml

from sdhn_experiments import budget_marks
from sdhn_experiments.figures import load_runs
from sdhn_experiments.heldout_eval import evaluate_set
from sdhn_experiments.protocol_report import report
from sdhn_policy.actor_runtime import ActorRuntime

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "models" / "maif-tiny-sdhn"


def _run(logdir: Path, method: str, seed: int, *, task: str = "maif-10", total: int = 3000,
         done: bool = False) -> Path:
    d = logdir / f"{task}__{method}__s{seed}"
    (d / "actors").mkdir(parents=True)
    cfg = {"env": {"name": task, "reward": "corrected", "max_steps": None},
           "algo": {"name": method}, "train": {"total_steps": total, "seed": seed},
           "sdhn": {}}
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))
    (d / "run.json").write_text(json.dumps({"suite": "synthetic", "method": method,
                                            "task": task, "seed": seed}))
    (d / "metrics.csv").write_text("step,wall_time,tag,value\n"
                                   "1000,0,eval/success_rate,0.5\n"
                                   "1000,0,eval/heldout_success_rate,0.5\n")
    if done:
        (d / "DONE.json").write_text("{}")
    return d


def _cached(d: Path, mark: int, mode: str, success: float, ratio: float) -> None:
    """A mark's cached result as evaluate_mark writes it (10 instances; no actor needed)."""
    ok = round(success * 10)
    (d / "actors" / f"step_{mark}.{mode}.json").write_text(json.dumps(
        {"summary": {"instances": 10, "success_rate": success, "makespan_ratio_mean": ratio,
                     "failures": {"deadlock": 10 - ok, "wander": 0}},
         "success": [int(i < ok) for i in range(10)], "length": [60] * 10}))


def test_a_marked_actor_is_evaluated_once_and_cached(tmp_path: Path) -> None:
    """The real path: the shipped maif-tiny actor exported at a mark, greedy and in its card's
    mode (sampled), equals evaluate_set on the same set; the cache answers the second time."""
    d = _run(tmp_path, "sdhn", 1, task="maif-tiny")
    for f in (TINY / "actor.safetensors", TINY / "actor.json"):
        shutil.copy(f, d / "actors" / f.name.replace("actor", "step_1000"))
    (run,) = load_runs(tmp_path)
    assert budget_marks.marked_actors(run) == {1000: d / "actors" / "step_1000.safetensors"}
    rt = ActorRuntime.from_file(TINY / "actor.safetensors")
    for mode, kwargs in (("greedy", {}), ("deployed", {"sample": True})):
        assert budget_marks.evaluate_mark(run, 1000, d / "actors" / "step_1000.safetensors",
                                          mode, planner_cache=None, compute=False,
                                          models=ROOT / "models") is None
        res = budget_marks.evaluate_mark(run, 1000, d / "actors" / "step_1000.safetensors",
                                         mode, planner_cache=None, compute=True,
                                         models=ROOT / "models")
        assert res is not None
        direct = evaluate_set(rt, "maif-tiny", "heldout_large", **kwargs)  # type: ignore[arg-type]
        assert res.success == [int(r.success) for r in direct]
        assert budget_marks.cache_path(run, 1000, mode).is_file()
        (d / "actors" / "step_1000.safetensors").rename(d / "actors" / "gone")
        again = budget_marks.evaluate_mark(run, 1000, d / "actors" / "gone", mode,
                                           planner_cache=None, compute=False)
        assert again == res
        (d / "actors" / "gone").rename(d / "actors" / "step_1000.safetensors")


def test_marks_per_budget_and_their_claims(tmp_path: Path) -> None:
    """Three seeds a side at 2 marks: SDHN ahead at the first, level at the second; the final
    greedy mark of a finished run is the protocol's own cache and its claims are not repeated;
    a run that has not reached a mark does not count there."""
    logdir, out = tmp_path / "logs", tmp_path / "out"
    for s in (1, 2, 3):
        for method, first in (("sdhn", 0.9), ("mappo", 0.6)):
            d = _run(logdir, method, s, done=True)
            for mark in (1000, 2000):
                (d / "actors" / f"step_{mark}.safetensors").write_bytes(b"")
            for mode in budget_marks.MODES:
                _cached(d, 1000, mode, first + 0.01 * s, 1.0 if method == "sdhn" else 1.5)
                _cached(d, 2000, mode, 0.8 + 0.01 * s, 1.1)
                if mode == "deployed":
                    _cached(d, 3000, mode, 0.95, 1.1)
            (d / "heldout_large.json").write_text(json.dumps(  # the protocol's final cache
                {"summary": {"instances": 10, "success_rate": 0.9, "makespan_ratio_mean": 1.1,
                             "maps_with_zero_success": 0,
                             "failures": {"episodes": 1, "deadlock": 1, "wander": 0}},
                 "records": [{"success": i > 0, "length": 60} for i in range(10)]}))
    late = _run(logdir, "mappo", 4)  # reached the first mark only
    for mode in budget_marks.MODES:
        _cached(late, 1000, mode, 0.1, 2.0)
    (late / "actors" / "step_1000.safetensors").write_bytes(b"")  # marks are found by file

    report(logdir, out, None, compute_absolute=False, reps=200)
    js = json.loads((out / "protocol.json").read_text())["budgets"]["maif-10"]
    assert js["1000"]["greedy"]["mappo"]["seeds"] == [1, 2, 3, 4]
    assert js["2000"]["greedy"]["mappo"]["seeds"] == [1, 2, 3]
    assert js["3000"]["greedy"]["sdhn"]["success"] == [0.9, 0.9, 0.9]  # the protocol's cache
    assert js["1000"]["deployed"]["mappo"]["poi_sdhn_over"]["point"] == 1.0
    assert js["1000"]["greedy"]["mappo"]["deadlocks_per_1000"][3] == 900.0
    claims = (out / "claims.md").read_text().splitlines()
    first = next(x for x in claims if "outperforms MAPPO on maif-10 (at 0.001M team steps, "
                                      "greedy)" in x)
    assert first.endswith("| reproduced |")
    second = next(x for x in claims if "(at 0.002M team steps, greedy)" in x and "outperf" in x)
    assert second.endswith("| inconclusive at this budget |")
    assert not any("(at 0.003M team steps, greedy)" in x for x in claims)  # the protocol's row
    assert any("(at 0.003M team steps, deployed)" in x for x in claims)
    me = json.loads((out / "marl_eval.json").read_text())["MAIF"]["maif-10"]
    assert len(me["sdhn@1000_deployed"]["2"]["absolute_metrics"]["success_rate"]) == 10
    assert (out / "budgets.png").is_file()


def test_an_unfinished_suite_reports_its_marks(tmp_path: Path) -> None:
    """No finished run yet: the report still gives the marks the runs have passed."""
    logdir, out = tmp_path / "logs", tmp_path / "out"
    for method in ("sdhn", "mappo"):
        d = _run(logdir, method, 1)
        for mode in budget_marks.MODES:
            _cached(d, 1000, mode, 0.7, 1.2)
        (d / "actors" / "step_1000.safetensors").write_bytes(b"")
    written = report(logdir, out, None, compute_absolute=False, reps=200)
    assert "sample_efficiency.png" not in {p.name for p in written}
    md = (out / "protocol.md").read_text()
    assert "| 1,000 | greedy | mappo | 1 | 0.700 |" in md
    assert "inconclusive: 1 seed" in (out / "claims.md").read_text()
