"""Choose a shipped MAIF model's stall rule on the validation set, then report it once on the
large held-out set: the rule is chosen on 1,000 instances (200 maps) that neither training nor
the reported figures use, so the held-out figures are not tuned on the set they report.

    .venv/bin/python scripts/tune_stall_rule.py models/maif-10-sdhn models/maif-16-sdhn \
        --out stall-rule.json --markdown docs/results/stall-rule.md

Per model: greedy play on the validation set; every rule of the grid (``--calm``,
``--progress``, ``--sample`` at ``--temperatures``), then the ``--refine-top`` best again at each
``--refine-temperatures``; the choice (``sdhn_experiments.stall_tuning.choose``: the fastest
rule within ``--tolerance`` of the best success rate, speed measured against greedy play on the
instances both complete). Then greedy play, the default rule (``StallRule()``, what the actor
nodes run unless told otherwise) and the chosen rule on the large held-out set, with success
intervals over maps and the makespan over the planner's (own completions, and paired over the
instances all of them completed). Progress goes to stdout, one line per evaluation.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from sdhn_experiments.heldout_eval import (
    default_planner_cache,
    evaluate_set,
    modes_table,
    paired_makespan_ratios,
    planner_makespans,
    records_json,
    set_checksum,
    set_instances,
    summarise,
    write_json,
)
from sdhn_experiments.stall_tuning import (
    CALM_STEPS,
    PROGRESS_STEPS,
    SAMPLE_STEPS,
    SUCCESS_TOLERANCE,
    TEMPERATURES,
    RuleScore,
    choose,
    pool,
    ranked,
    rule_grid,
    score,
)
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.stall_breaker import StallRule
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

TUNE_SET = "validation"
REPORT_SET = "heldout_large"


def _task(model: Path) -> str:
    card = model / "card.json"
    if not card.is_file():
        raise ValueError(f"{model}: not a model directory (no card.json)")
    task = str(json.loads(card.read_text()).get("env"))
    if task not in MAIF_CONFIGS:
        raise ValueError(f"{model}: the card's env {task!r} is not a MAIF task")
    return task


def tune(model: Path, grid: list[StallRule], *, refine: list[float], refine_top: int,
         tolerance: float, planner_cache: Path) -> dict[str, Any]:
    task = _task(model)
    rt = ActorRuntime.from_file(model / "actor.safetensors")
    t0 = time.monotonic()
    greedy = evaluate_set(rt, task, TUNE_SET)
    g_success = sum(r.success for r in greedy) / len(greedy)
    print(f"[tune] {model.name} {task}/{TUNE_SET}: greedy {g_success:.3f}", flush=True)

    def run(rule: StallRule, i: int, n: int) -> RuleScore:
        s = score(rule, evaluate_set(rt, task, TUNE_SET, stall=rule), greedy)
        slow = "-" if s.slowdown is None else f"{s.slowdown:.3f}"
        print(f"[tune] {model.name} [{i}/{n}] rule {rule.text()}: success {s.success_rate:.3f}, "
              f"makespan / greedy's {slow}, deadlocks {s.deadlocks} "
              f"({time.monotonic() - t0:.0f} s)", flush=True)
        return s

    scores = [run(rule, i + 1, len(grid)) for i, rule in enumerate(grid)]
    extra = [StallRule(s.rule.calm_steps, s.rule.progress_steps, s.rule.sample_steps, t)
             for s in ranked(scores, tolerance)[:refine_top] for t in refine
             if t != s.rule.temperature]
    scores += [run(rule, i + 1, len(extra)) for i, rule in enumerate(extra)]
    best = choose(scores, tolerance)
    print(f"[tune] {model.name}: chosen {best.rule.text()} (success {best.success_rate:.3f})",
          flush=True)

    inst = set_instances(task, REPORT_SET)
    plan = planner_makespans(task, REPORT_SET, planner_cache, progress=True)
    default = StallRule()
    modes: list[tuple[str, StallRule | None]] = [("greedy", None)]
    if best.rule == default:
        modes.append((f"default rule {default.text()} (also the chosen)", default))
    else:
        modes += [(f"default rule {default.text()}", default),
                  (f"chosen rule {best.rule.text()}", best.rule)]
    checksum = set_checksum(inst)
    report = []
    for mode, rule in modes:
        recs = evaluate_set(rt, task, REPORT_SET, stall=rule)
        summary = summarise(recs, plan, inst.num_formations)
        print(f"[report] {model.name} {task}/{REPORT_SET} {mode}: success "
              f"{summary['success_rate']:.3f}", flush=True)
        entry: dict[str, Any] = {
            "mode": mode, "rule": None if rule is None else rule.text(), "task": task,
            "set": REPORT_SET, "set_checksum": checksum, "summary": summary,
            "records": records_json(recs), "planner_makespan": plan}
        report.append(entry)
    paired_n, paired = paired_makespan_ratios(report)
    for r, p in zip(report, paired, strict=True):
        r["makespan_ratio_paired"] = p
        del r["records"], r["planner_makespan"]  # kept small: the summaries say what counts
    return {"model": model.name, "task": task,
            "validation": {"set": TUNE_SET,
                           "set_checksum": set_checksum(set_instances(task, TUNE_SET)),
                           "greedy_success": g_success, "tolerance": tolerance,
                           "scores": [s.as_json() for s in ranked(scores, tolerance)],
                           "chosen": best.rule.text()},
            "heldout_large": {"paired_instances": paired_n, "modes": report}}


def pooled(results: list[dict[str, Any]], tolerance: float = SUCCESS_TOLERANCE
           ) -> dict[str, Any] | None:
    """The rules every policy was scored with, averaged over the policies, and the one rule
    that serves them all best (a candidate for the actors' default); None for one policy."""
    if len(results) < 2:
        return None
    scores = ranked(pool([[RuleScore.from_json(e) for e in r["validation"]["scores"]]
                         for r in results]), tolerance)
    return {"models": [r["model"] for r in results], "scores": [s.as_json() for s in scores],
            "chosen": scores[0].rule.text()}


def _score_rows(scores: list[dict[str, Any]]) -> list[str]:
    out = ["| rule (calm, progress, sample[, T]) | success | makespan / greedy's | deadlocks |",
           "|---|---|---|---|"]
    for s in scores:
        slow = "–" if s["slowdown"] is None else f"{s['slowdown']:.3f}"
        out.append(f"| {s['rule']} | {s['success_rate']:.3f} | {slow} | {s['deadlocks']} |")
    return out


def markdown(results: list[dict[str, Any]], top: int = 5) -> str:
    out = []
    both = pooled(results)
    if both is not None:
        out += [f"### One rule for all: {', '.join(both['models'])}", "",
                f"Validation set, success and makespan / greedy's averaged over the policies; "
                f"the {top} best of {len(both['scores'])} rules; chosen: **{both['chosen']}**",
                "", *_score_rows(both["scores"][:top]), ""]
    for res in results:
        v = res["validation"]
        out += [f"### {res['model']} ({res['task']})", "",
                f"Validation set (1,000 instances; greedy {v['greedy_success']:.3f}), the "
                f"{top} best of {len(v['scores'])} rules; chosen: **{v['chosen']}**", "",
                *_score_rows(v["scores"][:top])]
        h = res["heldout_large"]
        out += ["", f"Large held-out set (paired makespan over the {h['paired_instances']} "
                "instances every mode completed)", ""]
        out += modes_table([(r["mode"], r["summary"], r["makespan_ratio_paired"])
                            for r in h["modes"]])
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("models", nargs="*", type=Path, help="model directories (card.json names "
                   "the MAIF task)")
    p.add_argument("--calm", nargs="+", type=int, default=list(CALM_STEPS))
    p.add_argument("--progress", nargs="+", type=int, default=list(PROGRESS_STEPS))
    p.add_argument("--sample", nargs="+", type=int, default=list(SAMPLE_STEPS))
    p.add_argument("--temperatures", nargs="+", type=float, default=list(TEMPERATURES))
    p.add_argument("--refine-temperatures", nargs="*", type=float, default=[0.5],
                   help="temperatures tried again for the best rules of the grid")
    p.add_argument("--refine-top", type=int, default=3)
    p.add_argument("--tolerance", type=float, default=SUCCESS_TOLERANCE,
                   help="rules within this of the best success rate count as equal")
    p.add_argument("--planner-cache", type=Path, default=default_planner_cache())
    p.add_argument("--out", type=Path, help="JSON: every score and the held-out summaries")
    p.add_argument("--markdown", type=Path, help="the tables")
    p.add_argument("--from-json", type=Path, metavar="JSON",
                   help="evaluate nothing: write the tables of an earlier --out file")
    args = p.parse_args(argv)
    if args.from_json is not None:
        try:
            results = json.loads(args.from_json.read_text())
            text = markdown(results)
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"tune_stall_rule: --from-json: {e}", file=sys.stderr)
            return 2
        return _emit(text, args.markdown)
    if not args.models:
        print("tune_stall_rule: name at least one model directory (or --from-json)",
              file=sys.stderr)
        return 2
    try:
        grid = rule_grid(args.calm, args.progress, args.sample, args.temperatures)
        for t in args.refine_temperatures:
            StallRule(temperature=t).check()
        if args.refine_top < 0 or not args.tolerance >= 0:
            raise ValueError("--refine-top and --tolerance must be >= 0")
        for m in args.models:
            _task(m)
    except ValueError as e:
        print(f"tune_stall_rule: {e}", file=sys.stderr)
        return 2
    results = []
    for m in args.models:
        results.append(tune(m, grid, refine=args.refine_temperatures,
                            refine_top=args.refine_top, tolerance=args.tolerance,
                            planner_cache=args.planner_cache))
        if args.out:  # after every model, so an interrupted sweep keeps what it finished
            write_json(args.out, results)
    return _emit(markdown(results), args.markdown)


def _emit(text: str, md: Path | None) -> int:
    if md is not None:
        md.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
