"""A suite's results under the evaluation protocol (docs/evaluation-protocol.md), from its log
directory only:

    protocol_report LOGDIR OUTDIR [--no-absolute]      (scripts/protocol_report.py)

Reads every finished run of LOGDIR (``DONE.json``; unfinished runs are listed, not counted) and
writes to OUTDIR:

- ``protocol.md`` / ``protocol.json``: per task and method, the final greedy success on the 100
  fixed instances and on the 100 held-out ones, and the **absolute metric** (the run's final
  actor re-evaluated on the 1,000-instance large held-out set, with its makespan over the
  planner's), each as IQM and mean with 95 % stratified bootstrap intervals over seeds; the
  probability of improvement of SDHN over every other method;
- ``sample_efficiency.png``: IQM of greedy success over training with 95 % bands, per task;
- ``marl_eval.json``: the same data in marl-eval's raw-data format;
- ``claims.md``: the paper's claims, our measurement with its interval, our budget against the
  paper's, and a verdict (reproduced / contradicted / inconclusive at this budget).

The absolute metric needs each run's ``actor.safetensors``; it is computed once per run and
cached in ``<run>/heldout_large.json`` (with the set's checksum; the planner's makespans in the
planner cache). All statistics come from ``protocol_stats`` (rliable).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_train.analysis import protocol_stats as ps
from sdhn_train.analysis.figures import FigureError, Run, load_runs

SUCCESS_TAGS = {"train": "eval/success_rate", "heldout": "eval/heldout_success_rate"}
PAPER_BUDGET = "10-20M"  # team-steps per run in the paper's configs
PAPER_MAKESPAN_RATIO = 0.77  # "a 23 % reduction in makespan compared to MAPPO"
LABELS = {"sdhn": "SDHN", "mappo": "MAPPO", "qmix": "QMIX", "dicg": "DICG",
          "hgcn_mix": "HGCN-MIX", "sdhn_wo_lsk": "SDHN w/o L_Sk", "sdhn_wo_shr": "SDHN w/o SHR",
          "sdhn_generator_1_layer": "SDHN, 1-layer generator"}
BASELINES = ("mappo", "qmix", "dicg", "hgcn_mix")
ABSOLUTE_FILE = "heldout_large.json"


@dataclass
class MethodData:
    """Per-run scores of one method on one task (runs in seed order)."""

    seeds: list[int] = field(default_factory=list)
    train: list[float] = field(default_factory=list)
    heldout: list[float] = field(default_factory=list)
    absolute: list[float | None] = field(default_factory=list)
    ratio: list[float | None] = field(default_factory=list)  # makespan / planner's, large set
    steps: list[int] = field(default_factory=list)  # team-steps each run trained
    runs: list[Run] = field(default_factory=list)

    def absolute_scores(self) -> list[float] | None:
        vals = self.absolute
        return None if not vals or any(v is None for v in vals) else [float(v) for v in vals
                                                                        if v is not None]

    def headline(self) -> tuple[str, list[float]]:
        """(which score, values): the absolute metric where every run has it, else held-out."""
        a = self.absolute_scores()
        return ("absolute", a) if a is not None else ("heldout", self.heldout)


def is_done(run: Run) -> bool:
    return (run.path / "DONE.json").is_file()


def absolute_metric(run: Run, planner_cache: Path | None, compute: bool) -> dict[str, Any] | None:
    """The run's final actor on the large held-out set (cached in the run directory)."""
    cache = run.path / ABSOLUTE_FILE
    actor = run.path / "actor.safetensors"
    if cache.is_file():
        return dict(json.loads(cache.read_text()))
    if not compute or not actor.is_file() or not run.task.startswith("maif"):
        return None
    from sdhn_policy.actor_runtime import ActorRuntime
    from sdhn_train.analysis.heldout_eval import (
        evaluate_set,
        planner_makespans,
        records_json,
        set_checksum,
        set_instances,
        summarise,
        write_json,
    )

    inst = set_instances(run.task, "heldout_large")
    recs = evaluate_set(ActorRuntime.from_file(actor), run.task, "heldout_large",
                        reward=run.reward)
    plan = planner_makespans(run.task, "heldout_large", planner_cache, progress=True)
    out: dict[str, Any] = {"set": "heldout_large", "set_checksum": set_checksum(inst),
                           "summary": summarise(recs, plan, inst.num_formations),
                           "records": records_json(recs)}
    write_json(cache, out)
    print(f"[protocol] {run.path.name}: large held-out success "
          f"{out['summary']['success_rate']:.3f}", flush=True)
    return out


def collect(runs: list[Run], planner_cache: Path | None,
            compute_absolute: bool) -> dict[str, dict[str, MethodData]]:
    """{task: {method: MethodData}} of the finished runs."""
    out: dict[str, dict[str, MethodData]] = defaultdict(lambda: defaultdict(MethodData))
    for r in sorted(runs, key=lambda r: (r.task, r.method, r.seed)):
        if not is_done(r):
            continue
        train, held = r.final(SUCCESS_TAGS["train"]), r.final(SUCCESS_TAGS["heldout"])
        if train is None or held is None:
            continue  # a run without a greedy evaluation (RWARE) is not part of this protocol
        d = out[r.task][r.method]
        d.seeds.append(r.seed)
        d.train.append(train)
        d.heldout.append(held)
        d.steps.append(int(r.config["train"]["total_steps"]))
        d.runs.append(r)
        ab = absolute_metric(r, planner_cache, compute_absolute)
        d.absolute.append(None if ab is None else float(ab["summary"]["success_rate"]))
        d.ratio.append(None if ab is None else ab["summary"].get("makespan_ratio_mean"))
    return out


def curves(data: MethodData) -> tuple[np.ndarray, np.ndarray] | None:
    """(steps [P], success [runs, P]) on the evaluation steps every run logged."""
    series = [r.series.get(SUCCESS_TAGS["train"]) for r in data.runs]
    if not series or any(s is None for s in series):
        return None
    common = sorted(set.intersection(*(set(s[0].tolist()) for s in series if s is not None)))
    if not common:
        return None
    vals = np.array([[dict(zip(s[0].tolist(), s[1].tolist(), strict=True))[k] for k in common]
                     for s in series if s is not None])
    return np.array(common), vals


def label(method: str) -> str:
    return LABELS.get(method, method)


def verdict(est: ps.Estimate, better_above: float) -> str:
    """'reproduced' when the interval lies above ``better_above``, 'contradicted' below it."""
    if est.low > better_above:
        return "reproduced"
    if est.high < better_above:
        return "contradicted"
    return "inconclusive at this budget"


def claims_rows(tasks: dict[str, dict[str, MethodData]],
                reps: int = ps.REPS) -> list[dict[str, str]]:
    rows = []
    for task in sorted(tasks):
        ms = tasks[task]
        if "sdhn" not in ms:
            continue
        sd = ms["sdhn"]
        which, sd_scores = sd.headline()
        budget = f"{max(sd.steps) / 1e6:g}M × {len(sd.seeds)} seeds"
        for base in (*BASELINES, "sdhn_wo_lsk", "sdhn_wo_shr"):
            if base not in ms:
                continue
            _, b_scores = ms[base].headline()
            poi = ps.probability_of_improvement(sd_scores, b_scores, reps)
            claim = (f"SDHN outperforms {label(base)} on {task}" if base in BASELINES else
                     f"{label(base)} is worse than SDHN on {task} (ablation)")
            rows.append({"claim": claim,
                         "measurement": f"P(SDHN > {label(base)}) = {poi.fmt()} ({which} "
                                        f"success, {len(b_scores)} seeds)",
                         "budget": budget, "verdict": verdict(poi, 0.5)})
        if "mappo" in ms:
            sm = [r for r in sd.ratio if r is not None]
            mm = [r for r in ms["mappo"].ratio if r is not None]
            if len(sm) == len(sd.ratio) and len(mm) == len(ms["mappo"].ratio) and sm and mm:
                ratio = ps.ratio_of_means(sm, mm, reps)
                v = ("reproduced" if ratio.high <= PAPER_MAKESPAN_RATIO else
                     "contradicted" if ratio.low > PAPER_MAKESPAN_RATIO else
                     "inconclusive at this budget")
                rows.append({"claim": f"SDHN's makespan is 23 % below MAPPO's on {task}",
                             "measurement": f"SDHN / MAPPO makespan (each over the planner's, "
                                            f"large held-out set) = {ratio.fmt(3)}",
                             "budget": budget, "verdict": v})
        if task in ("maif-16", "maif-20"):
            for base in ("qmix", "mappo"):
                if base not in ms:
                    continue
                w, scores = ms[base].headline()
                est = ps.interval_estimates({base: scores}, reps)[base]["mean"]
                v = ("reproduced" if est.high < 0.5 else "contradicted" if est.low >= 0.5 else
                     "inconclusive at this budget")
                rows.append({"claim": f"{label(base)} fails on {task} (success below 0.5)",
                             "measurement": f"{label(base)} mean {w} success {est.fmt()}",
                             "budget": budget, "verdict": v})
    return rows


def claims_markdown(rows: list[dict[str, str]], source: str) -> str:
    lines = [f"# The paper's claims, one by one ({source})", "",
             f"Budget: ours per run against the paper's ({PAPER_BUDGET} team-steps per run). "
             "A claim of superiority is **reproduced** when the 95 % interval of the probability "
             "of improvement lies above 0.5, **contradicted** when it lies below, else "
             "**inconclusive at this budget**. Written by `scripts/protocol_report.py`.", "",
             "| claim | our measurement [95 % CI] | budget (paper: "
             f"{PAPER_BUDGET}) | verdict |", "|---|---|---|---|"]
    lines += [f"| {r['claim']} | {r['measurement']} | {r['budget']} | {r['verdict']} |"
              for r in rows]
    return "\n".join(lines) + "\n"


def report(logdir: Path, outdir: Path, planner_cache: Path | None,
           compute_absolute: bool = True, reps: int = ps.REPS) -> list[Path]:
    runs = load_runs(logdir)
    tasks = collect(runs, planner_cache, compute_absolute)
    if not tasks:
        raise FigureError(f"{logdir}: no finished MAIF run (DONE.json and a greedy evaluation)")
    outdir.mkdir(parents=True, exist_ok=True)
    pending = sorted(r.path.name for r in runs if not is_done(r))
    summary: dict[str, Any] = {"logdir": logdir.name, "unfinished_runs": pending, "tasks": {}}
    md = [f"# Protocol report: {logdir.name}", "",
          "Final greedy success per method, IQM and mean over seeds with 95 % stratified "
          "bootstrap intervals (rliable). *fixed*: the 100 fixed training-map instances; "
          "*held-out*: the 100 held-out instances; *absolute*: the final actor on the "
          "1,000-instance large held-out set (200 maps), with its makespan over the "
          "planner's. Written by `scripts/protocol_report.py`.", ""]
    if pending:
        md += [f"Unfinished runs, not counted: {', '.join(pending)}", ""]
    for task in sorted(tasks):
        ms = tasks[task]
        md += [f"## {task}", "", "| method | seeds | steps | fixed IQM | fixed mean | "
               "held-out IQM | absolute IQM | absolute mean | makespan / planner | "
               "P(SDHN > it) |", "|---|---|---|---|---|---|---|---|---|---|"]
        tjson: dict[str, Any] = {}
        for m, d in ms.items():
            est = {k: ps.interval_estimates({m: v}, reps)[m] for k, v in
                   (("fixed", d.train), ("heldout", d.heldout)) if v}
            ab = d.absolute_scores()
            if ab is not None:
                est["absolute"] = ps.interval_estimates({m: ab}, reps)[m]
            poi = None
            if m != "sdhn" and "sdhn" in ms:
                poi = ps.probability_of_improvement(ms["sdhn"].headline()[1], d.headline()[1],
                                                    reps)
            ratios = [r for r in d.ratio if r is not None]
            tjson[m] = {"seeds": d.seeds, "steps": d.steps, "fixed": d.train,
                        "heldout": d.heldout, "absolute": d.absolute, "makespan_ratio": d.ratio,
                        **{f"{k}_{s}": e[s].to_json() for k, e in est.items()
                           for s in ("iqm", "mean")},
                        "poi_sdhn_over": None if poi is None else poi.to_json()}
            ab_iqm = est["absolute"]["iqm"].fmt() if "absolute" in est else "—"
            ab_mean = est["absolute"]["mean"].fmt() if "absolute" in est else "—"
            md.append(f"| {label(m)} | {len(d.seeds)} | {max(d.steps)} | "
                      f"{est['fixed']['iqm'].fmt()} | {est['fixed']['mean'].fmt()} | "
                      f"{est['heldout']['iqm'].fmt()} | {ab_iqm} | {ab_mean} | "
                      f"{f'{np.mean(ratios):.3f}' if ratios else '—'} | "
                      f"{'—' if poi is None else poi.fmt()} |")
        summary["tasks"][task] = tjson
        md.append("")
    written = [outdir / "protocol.md", outdir / "protocol.json", outdir / "marl_eval.json",
               outdir / "claims.md"]
    rows = claims_rows(tasks, reps)
    md += ["Claims: claims.md. Curves: sample_efficiency.png.", ""]
    written[0].write_text("\n".join(md))
    written[1].write_text(json.dumps(summary, indent=1) + "\n")
    written[2].write_text(json.dumps(ps.marl_eval_json(marl_runs(tasks)), indent=1) + "\n")
    written[3].write_text(claims_markdown(rows, f"suite logs {logdir.name}"))
    fig = sample_efficiency_figure(tasks, outdir / "sample_efficiency.png", reps)
    return written + ([fig] if fig else [])


def marl_runs(tasks: dict[str, dict[str, MethodData]]) -> list[dict[str, Any]]:
    out = []
    for task, ms in tasks.items():
        for m, d in ms.items():
            for i, r in enumerate(d.runs):
                s = r.series.get(SUCCESS_TAGS["train"])
                steps = [] if s is None else [(int(k), {"success_rate": [float(v)]})
                                              for k, v in zip(s[0], s[1], strict=True)]
                ab = None
                cache = r.path / ABSOLUTE_FILE
                if cache.is_file():
                    recs = json.loads(cache.read_text())["records"]
                    ab = {"success_rate": [float(x["success"]) for x in recs],
                          "episode_length": [float(x["length"]) for x in recs]}
                out.append({"env": "MAIF", "task": task, "algorithm": m,
                            "run": str(d.seeds[i]), "steps": steps, "absolute": ab})
    return out


def sample_efficiency_figure(tasks: dict[str, dict[str, MethodData]], out: Path,
                             reps: int = ps.REPS) -> Path | None:
    panels = []
    for task in sorted(tasks):
        lines = {}
        for m, d in tasks[task].items():
            c = curves(d)
            if c is not None:
                lines[m] = c
        if lines:
            panels.append((task, lines))
    if not panels:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.6), squeeze=False)
    for ax, (task, lines) in zip(axes[0], panels, strict=True):
        for m, (steps, vals) in lines.items():
            point, lo, hi = ps.curve_estimates({m: vals}, reps)[m]
            ax.plot(steps, point, label=f"{label(m)} ({vals.shape[0]})")
            ax.fill_between(steps, lo, hi, alpha=0.2)
        ax.set_title(f"{task}: greedy success (100 fixed instances)")
        ax.set_xlabel("team env-steps")
        ax.set_ylabel("IQM over seeds, 95 % CI")
        ax.set_ylim(0, 1.02)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="protocol_report",
                                description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("logdir", type=Path, help="a suite's log directory (run_experiments)")
    p.add_argument("outdir", type=Path, help="where the tables, figures and JSON go")
    p.add_argument("--no-absolute", action="store_true",
                   help="do not compute missing absolute metrics (use cached ones only)")
    p.add_argument("--planner-cache", type=Path, default=None,
                   help="planner makespan cache (default: $XDG_CACHE_HOME/sdhn/planner)")
    p.add_argument("--reps", type=int, default=ps.REPS, help="bootstrap resamples")
    args = p.parse_args(argv)
    if args.reps < 100:
        print("protocol_report: --reps must be an integer >= 100", file=sys.stderr)
        return 2
    cache = args.planner_cache
    if cache is None:
        import os

        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sdhn" / \
            "planner"
    try:
        for f in report(args.logdir, args.outdir, cache, not args.no_absolute, args.reps):
            print(f"[protocol] wrote {f}")
    except (FigureError, OSError, ValueError) as e:
        print(f"protocol_report: {e}", file=sys.stderr)
        return 2
    return 0
