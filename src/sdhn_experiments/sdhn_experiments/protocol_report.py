"""A suite's results under the evaluation protocol (docs/evaluation-protocol.md), from its log
directory only:

    protocol_report LOGDIR OUTDIR [--no-absolute]      (scripts/protocol_report.py)

Reads every finished run of LOGDIR (``DONE.json``; unfinished runs are listed with their latest
evaluation, not counted) and writes to OUTDIR:

- ``protocol.md`` / ``protocol.json``: per task and method, the final greedy score and the
  **absolute metric** (the run's final actor re-evaluated on episodes no training saw), each as
  IQM and mean with 95 % stratified bootstrap intervals over seeds; the probability of
  improvement of SDHN over every method it is paired with. The score depends on the task:

  - MAIF: success on the 100 fixed instances and on the 100 held-out ones; absolute: the
    1,000-instance large held-out set, with its makespan over the planner's;
  - RWARE: requested shelves delivered per 500-step episode (greedy, the training-time
    evaluation); absolute: 100 episodes from seed ``RWARE_EVAL_SEED`` (the shipped cards'
    episodes), beside random and both scripted policies on the same seeds;
- ``sample_efficiency.png``: IQM of the greedy score over training with 95 % bands, per task;
- ``marl_eval.json``: the same data in marl-eval's raw-data format;
- ``claims.md``: the paper's claims, our measurement with its interval, our budget against the
  paper's, and a verdict (reproduced / contradicted / inconclusive at this budget).

**Pairs.** A method named ``<baseline><variant>`` (``mappo``, ``mappo_ent01``) is compared with
``sdhn<variant>`` (``sdhn``, ``sdhn_ent01``) where the suite has it: the same settings, only the
algorithm differs. SDHN's own variants (ablations, the 1-layer generator) are compared with
``sdhn``.

The absolute metric needs each run's ``actor.safetensors``; it is computed once per run and
cached in the run directory (``heldout_large.json`` for MAIF, with the set's checksum and the
planner's makespans in the planner cache; ``absolute_deliveries.json`` for RWARE). All
statistics come from ``protocol_stats`` (rliable).
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

from sdhn_experiments import budget_marks
from sdhn_experiments import protocol_stats as ps
from sdhn_experiments.figures import FigureError, Run, load_runs
from sdhn_experiments.verdicts import (
    MIN_VERDICT_SEEDS,
    PAPER_BUDGET,
    makespan_verdict,
    too_few,
    verdict,
)
from sdhn_train.run_files import read_run_text, run_file

LABELS = {"sdhn": "SDHN", "mappo": "MAPPO", "qmix": "QMIX", "dicg": "DICG",
          "hgcn_mix": "HGCN-MIX", "sdhn_wo_lsk": "SDHN w/o L_Sk", "sdhn_wo_shr": "SDHN w/o SHR",
          "sdhn_generator_1_layer": "SDHN, 1-layer generator"}
BASELINES = ("mappo", "qmix", "dicg", "hgcn_mix")
ABLATIONS = ("sdhn_wo_lsk", "sdhn_wo_shr")


@dataclass(frozen=True)
class Domain:
    """What a task family is judged by."""

    env: str  # marl-eval's environment name
    metric: str  # marl-eval's metric name, and the score's name in the tables
    tag: str  # the training-time greedy evaluation's metrics.csv tag
    heldout_tag: str | None  # greedy score on held-out instances during training (MAIF)
    absolute_file: str  # the absolute metric's cache in the run directory
    absolute_key: str  # its summary's headline number
    digits: int  # decimals in the tables
    unit: str  # what the number counts, for the figure
    legend: str  # what the report's columns mean for this family


RWARE_ABSOLUTE_EPISODES = 100
MAIF = Domain(
    "MAIF", "success_rate", "eval/success_rate", "eval/heldout_success_rate",
    "heldout_large.json", "success_rate", 2, "greedy success (100 fixed instances)",
    "MAIF: *fixed*: greedy success on the 100 fixed training-map instances; *held-out*: on the "
    "100 held-out instances; *absolute*: the final actor on the 1,000-instance large held-out "
    "set (200 maps), with its makespan over the planner's, its failed episodes split into "
    "deadlocks (timed out with a robot wedged off its goal) and wanders, and its maps with no "
    "formation completed (means over seeds).")
RWARE = Domain(
    "RWARE", "deliveries", "eval/deliveries", None, "absolute_deliveries.json",
    "deliveries_mean", 1, "greedy deliveries per episode",
    "RWARE: requested shelves delivered per 500-step episode, greedy. *final*: the last "
    f"training-time evaluation; *absolute*: the final actor on {RWARE_ABSOLUTE_EPISODES} "
    "episodes no training drew (the seeds the shipped cards use), with random and both "
    "scripted policies on the same episodes.")


def domain_of(task: str) -> Domain:
    if task.startswith("maif"):
        return MAIF
    if task.startswith("rware"):
        return RWARE
    raise ValueError(f"task {task!r}: no protocol for it (allowed: maif-*, rware-*)")


@dataclass
class MethodData:
    """Per-run scores of one method on one task (runs in seed order)."""

    seeds: list[int] = field(default_factory=list)
    train: list[float] = field(default_factory=list)  # final greedy score (MAIF: fixed set)
    heldout: list[float] = field(default_factory=list)  # MAIF only
    absolute: list[float | None] = field(default_factory=list)
    ratio: list[float | None] = field(default_factory=list)  # makespan / planner's, large set
    failures: list[dict[str, Any] | None] = field(default_factory=list)  # large set (MAIF)
    steps: list[int] = field(default_factory=list)  # team-steps each run trained
    runs: list[Run] = field(default_factory=list)

    def absolute_scores(self) -> list[float] | None:
        vals = self.absolute
        return None if not vals or any(v is None for v in vals) else [float(v) for v in vals
                                                                        if v is not None]

    def headline(self) -> tuple[str, list[float]]:
        """(which score, values): the absolute metric where every run has it, else held-out
        (MAIF), else the training-time evaluation (RWARE)."""
        a = self.absolute_scores()
        if a is not None:
            return "absolute", a
        return ("heldout", self.heldout) if self.heldout else ("final", self.train)


def is_done(run: Run) -> bool:
    return (run.path / "DONE.json").is_file()


def absolute_metric(run: Run, planner_cache: Path | None, compute: bool) -> dict[str, Any] | None:
    """The run's final actor on episodes no training saw (cached in the run directory)."""
    dom = domain_of(run.task)
    cache = run.path / dom.absolute_file
    actor = run.path / "actor.safetensors"
    if run_file(cache).is_file():  # a carried suite's copy is packed
        return dict(json.loads(read_run_text(cache)))
    if not compute or not actor.is_file():
        return None
    from sdhn_experiments.heldout_eval import write_json
    from sdhn_policy.actor_runtime import ActorRuntime

    rt = ActorRuntime.from_file(actor)
    if dom is RWARE:
        from sdhn_policy.deploy_eval import RWARE_EVAL_SEED, rware_deliveries

        res = rware_deliveries(rt, run.task, RWARE_ABSOLUTE_EPISODES, RWARE_EVAL_SEED)
        out: dict[str, Any] = {
            "episodes": res["episodes"], "seeds": res["seeds"],
            "summary": {"deliveries_mean": res["deliveries_mean"],
                        "deliveries_std": res["deliveries_std"], "return": res["return"]},
            "records": [{"seed": RWARE_EVAL_SEED + i, "deliveries": k}
                        for i, k in enumerate(res["deliveries"])]}
        write_json(cache, out)
        print(f"[protocol] {run.path.name}: {res['deliveries_mean']:.1f} deliveries per episode "
              f"on seeds {res['seeds']}", flush=True)
        return out
    from sdhn_experiments.heldout_eval import (
        evaluate_set,
        planner_makespans,
        records_json,
        set_checksum,
        set_instances,
        summarise,
    )

    inst = set_instances(run.task, "heldout_large")
    recs = evaluate_set(rt, run.task, "heldout_large", reward=run.reward)
    plan = planner_makespans(run.task, "heldout_large", planner_cache, progress=True)
    out = {"set": "heldout_large", "set_checksum": set_checksum(inst),
           "summary": summarise(recs, plan, inst.num_formations),
           "records": records_json(recs)}
    write_json(cache, out)
    print(f"[protocol] {run.path.name}: large held-out success "
          f"{out['summary']['success_rate']:.3f}", flush=True)
    return out


def absolute_records(run: Run) -> dict[str, list[float]] | None:
    """marl-eval's ``absolute_metrics`` of a run: one value per evaluation episode."""
    dom = domain_of(run.task)
    cache = run.path / dom.absolute_file
    if not run_file(cache).is_file():
        return None
    recs = json.loads(read_run_text(cache))["records"]
    if dom is RWARE:
        return {"deliveries": [float(x["deliveries"]) for x in recs]}
    return {"success_rate": [float(x["success"]) for x in recs],
            "episode_length": [float(x["length"]) for x in recs]}


def collect(runs: list[Run], planner_cache: Path | None,
            compute_absolute: bool) -> dict[str, dict[str, MethodData]]:
    """{task: {method: MethodData}} of the finished runs."""
    out: dict[str, dict[str, MethodData]] = defaultdict(lambda: defaultdict(MethodData))
    for r in sorted(runs, key=lambda r: (r.task, r.method, r.seed)):
        if not is_done(r):
            continue
        dom = domain_of(r.task)
        train = r.final(dom.tag)
        held = r.final(dom.heldout_tag) if dom.heldout_tag else None
        if train is None or (dom.heldout_tag and held is None):
            continue  # a run without a greedy evaluation is not part of this protocol
        d = out[r.task][r.method]
        d.seeds.append(r.seed)
        d.train.append(train)
        if held is not None:
            d.heldout.append(held)
        d.steps.append(int(r.config["train"]["total_steps"]))
        d.runs.append(r)
        ab = absolute_metric(r, planner_cache, compute_absolute)
        d.absolute.append(None if ab is None else float(ab["summary"][dom.absolute_key]))
        d.ratio.append(None if ab is None else ab["summary"].get("makespan_ratio_mean"))
        d.failures.append(None if ab is None or dom is not MAIF else
                          {"deadlock": ab["summary"]["failures"]["deadlock"],
                           "wander": ab["summary"]["failures"]["wander"],
                           "maps_with_zero_success": ab["summary"]["maps_with_zero_success"]})
    return out


def curves(data: MethodData) -> tuple[np.ndarray, np.ndarray] | None:
    """(steps [P], success [runs, P]) on the evaluation steps every run logged."""
    series = [r.series.get(domain_of(r.task).tag) for r in data.runs]
    if not series or any(s is None for s in series):
        return None
    common = sorted(set.intersection(*(set(s[0].tolist()) for s in series if s is not None)))
    if not common:
        return None
    vals = np.array([[dict(zip(s[0].tolist(), s[1].tolist(), strict=True))[k] for k in common]
                     for s in series if s is not None])
    return np.array(common), vals


def label(method: str) -> str:
    """'MAPPO' for mappo, 'MAPPO (ent01)' for a variant mappo_ent01."""
    if method in LABELS:
        return LABELS[method]
    for base in sorted(LABELS, key=len, reverse=True):
        if method.startswith(base + "_"):
            return f"{LABELS[base]} ({method[len(base) + 1:]})"
    return method


def split_variant(method: str) -> tuple[str, str] | None:
    """(baseline, variant suffix) of a baseline method: mappo_ent01 -> (mappo, _ent01)."""
    for base in sorted(BASELINES, key=len, reverse=True):
        if method == base or method.startswith(base + "_"):
            return base, method[len(base):]
    return None


def sdhn_partner(method: str, methods: Any) -> str | None:
    """The SDHN method ``method`` is compared with (see Pairs above), if the suite has it."""
    if method.startswith("sdhn"):
        return "sdhn" if method != "sdhn" and "sdhn" in methods else None
    split = split_variant(method)
    if split is None:
        return None
    partner = "sdhn" + split[1]
    return partner if partner in methods else None


def _budget(d: MethodData) -> str:
    """A method's budget as the claims table states it: steps per run × seeds."""
    return f"{max(d.steps) / 1e6:g}M × {len(d.seeds)} seeds"


def claims_rows(tasks: dict[str, dict[str, MethodData]],
                reps: int = ps.REPS) -> list[dict[str, str]]:
    rows = []
    for task in sorted(tasks):
        ms = tasks[task]
        dom = domain_of(task)
        for base in ms:
            sdhn = sdhn_partner(base, ms)
            split = split_variant(base)
            if sdhn is None or (split is None and base not in ABLATIONS):
                continue
            sd = ms[sdhn]
            which, sd_scores = sd.headline()
            budget = _budget(sd)
            _, b_scores = ms[base].headline()
            poi = ps.probability_of_improvement(sd_scores, b_scores, reps)
            if split is not None:
                at = f" (both at the `{split[1][1:]}` settings)" if split[1] else ""
                claim = f"SDHN outperforms {label(split[0])} on {task}{at}"
            else:
                claim = f"{label(base)} is worse than SDHN on {task} (ablation)"
            rows.append({"claim": claim,
                         "measurement": f"P({label(sdhn)} > {label(base)}) = "
                                        f"{_est(poi, len(sd_scores), len(b_scores))} "
                                        f"({which} {dom.metric}, {len(sd_scores)} vs "
                                        f"{len(b_scores)} seeds)",
                         "budget": budget,
                         "verdict": too_few(len(sd_scores), len(b_scores)) or verdict(poi, 0.5)})
        if dom is MAIF and "sdhn" in ms and "mappo" in ms:
            sd = ms["sdhn"]
            budget = _budget(sd)
            sm = [r for r in sd.ratio if r is not None]
            mm = [r for r in ms["mappo"].ratio if r is not None]
            if len(sm) == len(sd.ratio) and len(mm) == len(ms["mappo"].ratio) and sm and mm:
                ratio = ps.ratio_of_means(sm, mm, reps)
                v = too_few(len(sm), len(mm)) or makespan_verdict(ratio)
                rows.append({"claim": f"SDHN's makespan is 23 % below MAPPO's on {task}",
                             "measurement": f"SDHN / MAPPO makespan (each over the planner's, "
                                            f"large held-out set) = "
                                            f"{_est(ratio, len(sm), len(mm), digits=3)}",
                             "budget": budget, "verdict": v})
        if task in ("maif-16", "maif-20"):
            for base in ("qmix", "mappo"):
                if base not in ms:
                    continue
                w, scores = ms[base].headline()
                est = ps.interval_estimates({base: scores}, reps)[base]["mean"]
                v = too_few(len(scores)) or (
                    "reproduced" if est.high < 0.5 else "contradicted" if est.low >= 0.5 else
                    "inconclusive at this budget")
                rows.append({"claim": f"{label(base)} fails on {task} (success below 0.5)",
                             "measurement": f"{label(base)} mean {w} success "
                                            f"{_est(est, len(scores))}",
                             "budget": _budget(ms[base]),
                             "verdict": v})
    return rows


def claims_markdown(rows: list[dict[str, str]], source: str) -> str:
    lines = [f"# The paper's claims, one by one ({source})", "",
             f"Budget: ours per run against the paper's ({PAPER_BUDGET} team-steps per run). "
             "A claim of superiority is **reproduced** when the 95 % interval of the probability "
             "of improvement lies above 0.5, **contradicted** when it lies below, else "
             "**inconclusive at this budget**; with fewer than "
             f"{MIN_VERDICT_SEEDS} seeds on a side there is no verdict. Written by "
             "`scripts/protocol_report.py`.", "",
             "| claim | our measurement [95 % CI] | budget (paper: "
             f"{PAPER_BUDGET}) | verdict |", "|---|---|---|---|"]
    lines += [f"| {r['claim']} | {r['measurement']} | {r['budget']} | {r['verdict']} |"
              for r in rows]
    return "\n".join(lines) + "\n"


def reference_policies(task: str, cache: Path, compute: bool) -> dict[str, float] | None:
    """RWARE: deliveries per episode of random and both scripted policies on the absolute
    metric's episodes, cached in ``cache`` (a JSON file of {task: {policy: mean}}), in the
    order of ``POLICIES`` whether computed or read (the report is the same either way)."""
    from sdhn_sim.envs.rware_baselines import POLICIES

    known: dict[str, Any] = json.loads(cache.read_text()) if cache.is_file() else {}
    if task not in known:
        if not compute:
            return None
        from sdhn_policy.deploy_eval import RWARE_EVAL_SEED
        from sdhn_sim.envs.rware_baselines import evaluate_baseline

        known[task] = {p: evaluate_baseline(task, p, episodes=RWARE_ABSOLUTE_EPISODES,
                                            seed=RWARE_EVAL_SEED)["deliveries_mean"]
                       for p in POLICIES}
        cache.write_text(json.dumps(known, indent=1, sort_keys=True) + "\n")
    order = [p for p in POLICIES if p in known[task]] + sorted(set(known[task]) - set(POLICIES))
    return {p: float(known[task][p]) for p in order}


def _est(e: ps.Estimate, *runs: int, digits: int = 2) -> str:
    """The estimate with its interval, or the bare value when every side has one run."""
    return f"{e.point:.{digits}f}" if max(runs) == 1 else e.fmt(digits)


def _cell(est: dict[str, ps.Estimate] | None, stat: str, runs: int, digits: int) -> str:
    """A table cell: the estimate with its interval, the bare value for one run, or a dash."""
    return "—" if est is None else _est(est[stat], runs, digits=digits)


def _task_table(task: str, ms: dict[str, MethodData], reps: int
                ) -> tuple[list[str], dict[str, Any]]:
    """The task's markdown table rows and its protocol.json entry."""
    dom = domain_of(task)
    k = dom.digits
    if dom is MAIF:
        head = ("| method | seeds | steps | fixed IQM | fixed mean | held-out IQM | absolute IQM | "
                "absolute mean | makespan / planner | deadlocks, wanders | maps at 0 | "
                "P(SDHN > it) |")
    else:
        head = ("| method | seeds | steps | final IQM | final mean | absolute IQM | "
                "absolute mean | P(SDHN > it) |")
    md = [head, "|" + "---|" * (head.count("|") - 1)]
    first = "fixed" if dom is MAIF else "final"  # the training-time evaluation's score
    tjson: dict[str, Any] = {}
    for m, d in ms.items():
        est = {name: ps.interval_estimates({m: v}, reps)[m] for name, v in
               ((first, d.train), ("heldout", d.heldout)) if v}
        ab = d.absolute_scores()
        if ab is not None:
            est["absolute"] = ps.interval_estimates({m: ab}, reps)[m]
        partner = sdhn_partner(m, ms)
        poi = None if partner is None else ps.probability_of_improvement(
            ms[partner].headline()[1], d.headline()[1], reps)
        ratios = [r for r in d.ratio if r is not None]
        tjson[m] = {"seeds": d.seeds, "steps": d.steps, first: d.train,
                    "heldout": d.heldout, "absolute": d.absolute, "makespan_ratio": d.ratio,
                    "failures": d.failures,
                    **{f"{name}_{s}": e[s].to_json() for name, e in est.items()
                       for s in ("iqm", "mean")},
                    "sdhn_partner": partner,
                    "poi_sdhn_over": None if poi is None else poi.to_json()}

        poi_s = "—"
        if poi is not None and partner is not None:
            sides = (len(ms[partner].seeds), len(d.seeds))
            poi_s = _est(poi, *sides) + (" (1 vs 1 seed)" if max(sides) == 1 else "")
            if partner != "sdhn":
                poi_s += f" ({label(partner)})"
        n = len(d.seeds)
        cells = [label(m), str(n), str(max(d.steps)), _cell(est.get(first), "iqm", n, k),
                 _cell(est.get(first), "mean", n, k)]
        if dom is MAIF:
            cells.append(_cell(est.get("heldout"), "iqm", n, k))
        cells += [_cell(est.get("absolute"), "iqm", n, k), _cell(est.get("absolute"), "mean", n, k)]
        if dom is MAIF:
            cells.append(f"{np.mean(ratios):.3f}" if ratios else "—")
            fails = [f for f in d.failures if f is not None]
            cells += ([f"{np.mean([f['deadlock'] for f in fails]):.1f}, "
                       f"{np.mean([f['wander'] for f in fails]):.1f}",
                       f"{np.mean([f['maps_with_zero_success'] for f in fails]):.1f}"]
                      if fails else ["—", "—"])
        md.append("| " + " | ".join([*cells, poi_s]) + " |")
    return md, tjson


def in_progress(runs: list[Run]) -> list[dict[str, Any]]:
    """Where each unfinished run stands: its latest greedy evaluation and the step it was
    taken at (a run resumes from its last checkpoint, at or after that step)."""
    out = []
    for r in sorted(runs, key=lambda r: (r.task, r.method, r.seed)):
        if is_done(r):
            continue
        steps, values = r.series.get(domain_of(r.task).tag, (np.empty(0), np.empty(0)))
        latest = len(steps) > 0
        out.append({"run": r.path.name, "task": r.task, "method": r.method, "seed": r.seed,
                    "total_steps": int(r.config["train"]["total_steps"]),
                    "eval_step": int(steps[-1]) if latest else None,
                    "score": float(values[-1]) if latest else None})
    return out


def in_progress_table(progress: list[dict[str, Any]]) -> list[str]:
    md = ["## Unfinished runs (not counted)", "",
          "Runs the logs hold short of their budget: their latest greedy evaluation during "
          "training (MAIF: the fixed instances; RWARE: deliveries per episode), not a result.", "",
          "| run | latest evaluation | at step | of |", "|---|---|---|---|"]
    for p in progress:
        digits = domain_of(p["task"]).digits
        score = "—" if p["score"] is None else f"{p['score']:.{digits}f}"
        step = "—" if p["eval_step"] is None else f"{p['eval_step']:,}"
        md.append(f"| {p['run']} | {score} | {step} | {p['total_steps']:,} |")
    return [*md, ""]


def report(logdir: Path, outdir: Path, planner_cache: Path | None,
           compute_absolute: bool = True, reps: int = ps.REPS, *,
           models: Path = budget_marks.SHIPPED) -> list[Path]:
    runs = load_runs(logdir)
    tasks = collect(runs, planner_cache, compute_absolute)
    marks = budget_marks.collect(runs, planner_cache, compute_absolute, models)
    if not tasks and not marks:
        raise FigureError(f"{logdir}: no finished run with a greedy evaluation (DONE.json and "
                          "eval/success_rate or eval/deliveries in metrics.csv) and no actor "
                          "exported at a log.actor_marks mark")
    outdir.mkdir(parents=True, exist_ok=True)
    progress = in_progress(runs)
    summary: dict[str, Any] = {"logdir": logdir.name,
                               "unfinished_runs": sorted(p["run"] for p in progress),
                               "in_progress": progress, "tasks": {}}
    md = [f"# Protocol report: {logdir.name}", "",
          "Final greedy score per method, IQM and mean over seeds with 95 % stratified "
          "bootstrap intervals (rliable); one seed has no interval. P(SDHN > it): the "
          "probability of improvement of the paired SDHN method (SDHN at the same settings, "
          "named in brackets where it is a variant) on the absolute metric. Written by "
          "`scripts/protocol_report.py`.", ""]
    for dom in (MAIF, RWARE):
        if any(domain_of(t) is dom for t in tasks):
            md += [dom.legend, ""]
    if progress:
        md += in_progress_table(progress)
    refs_cache = outdir / "reference_policies.json"
    for task in sorted(tasks):
        rows, tjson = _task_table(task, tasks[task], reps)
        md += [f"## {task}", "", *rows, ""]
        if domain_of(task) is RWARE:
            refs = reference_policies(task, refs_cache, compute_absolute)
            if refs is not None:
                tjson["reference_policies"] = refs
                md += ["Reference policies on the same episodes (deliveries per episode): " +
                       ", ".join(f"{p} {v:.1f}" for p, v in refs.items()) + ".", ""]
        summary["tasks"][task] = tjson
    written = [outdir / "protocol.md", outdir / "protocol.json", outdir / "marl_eval.json",
               outdir / "claims.md"]
    claims = claims_rows(tasks, reps)
    marl = marl_runs(tasks)
    figs = [sample_efficiency_figure(tasks, outdir / "sample_efficiency.png", reps)]
    if marks:
        rows, summary["budgets"] = budget_marks.tables(marks, reps)
        md += [*rows, "Success against the budget: budgets.png.", ""]
        finals = {r.task: int(r.config["train"]["total_steps"]) for r in runs}
        claims += budget_marks.claims_rows(marks, finals, reps)
        marl += budget_marks.marl_absolute(marks)
        figs.append(budget_marks.figure(marks, outdir / "budgets.png", reps))
    md += ["Claims: claims.md." + (" Curves: sample_efficiency.png." if figs[0] else ""), ""]
    written[0].write_text("\n".join(md))
    written[1].write_text(json.dumps(summary, indent=1) + "\n")
    written[2].write_text(json.dumps(ps.marl_eval_json(marl), indent=1) + "\n")
    written[3].write_text(claims_markdown(claims, f"suite logs {logdir.name}"))
    return written + [f for f in figs if f is not None]


def marl_runs(tasks: dict[str, dict[str, MethodData]]) -> list[dict[str, Any]]:
    out = []
    for task, ms in tasks.items():
        dom = domain_of(task)
        for m, d in ms.items():
            for i, r in enumerate(d.runs):
                s = r.series.get(dom.tag)
                steps = [] if s is None else [(int(k), {dom.metric: [float(v)]})
                                              for k, v in zip(s[0], s[1], strict=True)]
                out.append({"env": dom.env, "task": task, "algorithm": m,
                            "run": str(d.seeds[i]), "steps": steps,
                            "absolute": absolute_records(r)})
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
        dom = domain_of(task)
        ax.set_title(f"{task}: {dom.unit}", fontsize=9)
        ax.set_xlabel("team env-steps")
        ax.set_ylabel("IQM over seeds, 95 % CI")
        if dom is MAIF:
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
    p.add_argument("--models", type=Path, default=budget_marks.SHIPPED,
                   help="shipped models whose cards name each task's deployed mode, for the "
                        "actors exported at log.actor_marks (default: models)")
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
        for f in report(args.logdir, args.outdir, cache, not args.no_absolute, args.reps,
                        models=args.models):
            print(f"[protocol] wrote {f}")
    except (FigureError, OSError, ValueError) as e:
        print(f"protocol_report: {e}", file=sys.stderr)
        return 2
    return 0
