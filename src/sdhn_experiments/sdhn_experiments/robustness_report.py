"""The robustness suite's report (``robustness`` writes the per-actor results it reads).

    write_report(Path("docs/results/robustness/raw"), Path("docs/results/robustness"))

Writes to the output directory:

- ``robustness.md`` / ``robustness.json``: per task, condition and severity (severity 0 is the
  ideal world), each method's mean over seeds of success (MAIF; under robot failure the
  survivors' success) or deliveries per episode (RWARE), and of the makespan over the planner's
  (MAIF), with 95 % stratified bootstrap intervals over seeds (the protocol's statistics, as
  ``protocol_stats`` computes them with rliable, vectorised here: ``boot_mean``, ``boot_poi``);
  the probability of improvement of SDHN over each method it is paired with, at each severity;
  the shipped models' figures (one actor each: no interval over seeds);
- ``robustness_<task>.png``: the degradation curves;
- ``marl_eval.json``: marl-eval's raw-data format, one "task" per (task, condition, severity),
  the per-instance values as absolute metrics;
- the verdict on the paper's uncertainty claim (``claim``): SDHN against SDHN w/o SHR, the
  ablation that removes the stochastic hyperedges. The direct test is the loss a condition
  causes: per seed, the score under a condition minus the same actor's ideal-world score,
  averaged over every condition and severity (one number per seed: the settings share their
  seeds, so they are not independent tasks), and P(SDHN loses less) over seeds. Reproduced when
  its 95 % interval lies above 0.5, contradicted when below, inconclusive otherwise. Beside it:
  the same with the settings taken as rliable's tasks (narrower: it treats them as
  independent), per condition, and P(SDHN scores higher) under the conditions.
"""

from __future__ import annotations

import json
import lzma
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_experiments import protocol_stats as ps
from sdhn_experiments.heldout_eval import write_json
from sdhn_experiments.protocol_report import ABLATIONS, BASELINES, MIN_VERDICT_SEEDS, label

GENERATOR = "sdhn_generator_1_layer"
SHR = "sdhn_wo_shr"
Key = tuple[str, int]  # (condition, level)


REPS = 5000


def boot_mean(x: npt.ArrayLike, reps: int = REPS, seed: int = 0) -> ps.Estimate:
    """Mean over runs with a 95 % percentile bootstrap interval (runs resampled): what
    ``protocol_stats.interval_estimates`` gives for one task, vectorised (the report needs
    thousands of them on a loaded machine; ``test_robustness`` holds the two together)."""
    a = np.asarray(x, dtype=np.float64)
    if len(a) < 2 or np.all(a == a[0]):
        return ps.Estimate(float(a.mean()), float(a.mean()), float(a.mean()))
    rng = np.random.default_rng(seed)
    m = a[rng.integers(0, len(a), (reps, len(a)))].mean(axis=1)
    lo, hi = np.percentile(m, [2.5, 97.5])
    return ps.Estimate(float(a.mean()), float(lo), float(hi))


def _poi(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) per task (ties a half) over the last axis' tasks: x [..., nx, T], y [..., ny, T]
    -> [..., T], averaged over tasks by the caller."""
    gt = (x[..., :, None, :] > y[..., None, :, :]).mean(axis=(-3, -2))
    eq = (x[..., :, None, :] == y[..., None, :, :]).mean(axis=(-3, -2))
    return np.asarray(gt + 0.5 * eq)


def boot_poi(x: npt.ArrayLike, y: npt.ArrayLike, reps: int = REPS, seed: int = 0
             ) -> ps.Estimate:
    """rliable's probability of improvement ([runs, tasks] each; Mann-Whitney U / (nx ny) per
    task, averaged over tasks) with its 95 % interval from independent stratified bootstraps of
    X and Y (runs resampled within each task), vectorised like ``boot_mean``."""
    ax, ay = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    sx, sy = ax.reshape(len(ax), -1), ay.reshape(len(ay), -1)
    point = float(_poi(sx, sy).mean())
    if len(sx) == 1 and len(sy) == 1:
        return ps.Estimate(point, point, point)
    rng = np.random.default_rng(seed)
    t = np.arange(sx.shape[1])
    xs = sx[rng.integers(0, len(sx), (reps, len(sx), len(t))), t]
    ys = sy[rng.integers(0, len(sy), (reps, len(sy), len(t))), t]
    p = _poi(xs, ys).mean(axis=-1)
    lo, hi = np.percentile(p, [2.5, 97.5])
    return ps.Estimate(point, float(lo), float(hi))


def load_results(results: Path) -> list[dict[str, Any]]:
    """Every per-actor result in the directory (``*.json``, or ``*.json.xz`` as committed)."""
    out = []
    for f in sorted([*results.glob("*.json"), *results.glob("*.json.xz")]):
        raw = lzma.decompress(f.read_bytes()) if f.suffix == ".xz" else f.read_bytes()
        d = json.loads(raw)
        if d.get("format") == "sdhn-robustness/1":
            out.append(d)
    return out


def reference(method: str, methods: set[str]) -> str | None:
    """The SDHN method ``method`` is compared with (the protocol's pairs), or None."""
    if method in (*ABLATIONS, GENERATOR):
        return "sdhn" if "sdhn" in methods else None
    for base in sorted(BASELINES, key=len, reverse=True):
        if method.startswith(base):
            ref = "sdhn" + method[len(base):]
            return ref if ref in methods else None
    return None


def primary(task: str) -> str:
    return "success_rate" if task.startswith("maif") else "deliveries_mean"


def by_method(results: list[dict[str, Any]]) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """{task: {method: [result per seed, in seed order]}} of the protocol actors."""
    out: dict[str, dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for r in results:
        if r.get("seed") is not None and "suite" in r.get("source", {}):
            out[r["task"]][r["policy"]].append(r)
    for t in out.values():
        for rs in t.values():
            rs.sort(key=lambda r: r["seed"])
    return out


def scores(runs: list[dict[str, Any]], metric: str) -> dict[Key, list[float | None]]:
    """{(condition, level): per-seed values of ``metric`` (None where undefined)}; the ideal
    world is (\"ideal\", 0)."""
    out: dict[Key, list[float | None]] = defaultdict(list)
    for r in runs:
        for s in r["settings"]:
            out[(s["condition"], s["level"])].append(s["summary"].get(metric))
    return out


def settings_of(runs: list[dict[str, Any]]) -> list[tuple[str, int, float]]:
    return [(s["condition"], s["level"], s["severity"]) for s in runs[0]["settings"]]


def estimate(vals: list[float | None]) -> tuple[ps.Estimate | None, int]:
    """Mean over seeds with its 95 % stratified bootstrap interval (seeds with no value left
    out), and the number of seeds it rests on."""
    v = [x for x in vals if x is not None]
    if not v:
        return None, 0
    return boot_mean(v), len(v)


def condition_losses(runs: list[dict[str, Any]], metric: str) -> np.ndarray:
    """[seeds, settings]: each non-ideal setting's score minus the same actor's ideal score."""
    rows = []
    for r in runs:
        ideal = next(s["summary"][metric] for s in r["settings"] if s["level"] == 0)
        rows.append([s["summary"][metric] - ideal for s in r["settings"] if s["level"] > 0])
    return np.asarray(rows, dtype=np.float64)


def condition_scores(runs: list[dict[str, Any]], metric: str) -> np.ndarray:
    return np.asarray([[s["summary"][metric] for s in r["settings"] if s["level"] > 0]
                       for r in runs], dtype=np.float64)


def claim_verdict(sdhn: list[dict[str, Any]], other: list[dict[str, Any]], metric: str
                  ) -> dict[str, Any]:
    """The uncertainty claim's test (see the module docstring)."""
    if len(sdhn) < MIN_VERDICT_SEEDS or len(other) < MIN_VERDICT_SEEDS:
        return {"verdict": "no verdict", "why": f"fewer than {MIN_VERDICT_SEEDS} seeds a side",
                "seeds": [len(sdhn), len(other)]}
    ls_, lo_ = condition_losses(sdhn, metric), condition_losses(other, metric)
    seed = boot_poi(ls_.mean(axis=1)[:, None], lo_.mean(axis=1)[:, None])
    loss = boot_poi(ls_, lo_)
    under = boot_poi(condition_scores(sdhn, metric), condition_scores(other, metric))
    verdict = ("reproduced" if seed.low > 0.5 else "contradicted" if seed.high < 0.5
               else "inconclusive")
    ls, lo = ls_.mean(), lo_.mean()
    names = [st["condition"] for st in sdhn[0]["settings"] if st["level"] > 0]
    per: dict[str, Any] = {}
    for c in dict.fromkeys(names):
        cols = [i for i, n in enumerate(names) if n == c]
        per[c] = boot_poi(ls_[:, cols], lo_[:, cols]).to_json()
    return {"verdict": verdict, "seeds": [len(sdhn), len(other)],
            "p_smaller_loss_per_condition": per, "p_smaller_loss_seeds": seed.to_json(),
            "mean_loss_per_seed": [ls_.mean(axis=1).tolist(), lo_.mean(axis=1).tolist()],
            "settings": int(condition_losses(sdhn, metric).shape[1]),
            "p_smaller_loss_settings_as_tasks": loss.to_json(),
            "p_better_under_conditions": under.to_json(),
            "mean_loss_sdhn": float(ls), "mean_loss_other": float(lo)}


def _fmt(est: tuple[ps.Estimate | None, int], digits: int) -> str:
    """The mean [95 % CI]; one seed has no interval over seeds (its point only)."""
    e, n = est
    if e is None:
        return "—"
    return f"{e.point:.{digits}f}" if n < 2 else e.fmt(digits)


def task_tables(task: str, methods: dict[str, list[dict[str, Any]]]) -> tuple[list[str],
                                                                               dict[str, Any]]:
    """Markdown lines and JSON of one task."""
    metric = primary(task)
    digits = 2 if task.startswith("maif") else 1
    names = sorted(methods, key=lambda m: (m != "sdhn" and not m.startswith("sdhn_ent"), m))
    any_runs = next(iter(methods.values()))
    sett = settings_of(any_runs)
    conds = list(dict.fromkeys(c for c, lvl, _ in sett if lvl > 0))
    sev = {(c, lvl): v for c, lvl, v in sett}
    js: dict[str, Any] = {"metric": metric, "methods": {}, "poi": {}}
    est: dict[str, dict[Key, tuple[ps.Estimate | None, int]]] = {}
    ratio_est: dict[str, dict[Key, tuple[ps.Estimate | None, int]]] = {}
    for m in names:
        sc = scores(methods[m], metric)
        est[m] = {k: estimate(v) for k, v in sc.items()}
        js["methods"][m] = {"seeds": [r["seed"] for r in methods[m]], "settings": {}}
        if task.startswith("maif"):
            rs = scores(methods[m], "makespan_over_planner")
            ratio_est[m] = {k: estimate(v) for k, v in rs.items()}
        for k, (e, n) in est[m].items():
            entry: dict[str, Any] = {"condition": k[0], "level": k[1], "severity": sev[k],
                                     metric: None if e is None else e.to_json(), "seeds_n": n}
            if m in ratio_est:
                re_, rn = ratio_est[m][k]
                entry["makespan_over_planner"] = None if re_ is None else re_.to_json()
                entry["makespan_seeds_n"] = rn
            js["methods"][m]["settings"][f"{k[0]}/{k[1]}"] = entry
    lines = [f"## {task}", "",
             f"Seeds per method: {', '.join(f'{label(m)} {len(methods[m])}' for m in names)}; "
             f"{any_runs[0].get('instances', any_runs[0].get('episodes'))} "
             f"{'instances of the large held-out set' if metric == 'success_rate' else 'episodes'}"
             " per setting.", ""]
    what = ("success (survivors' under failure)" if metric == "success_rate"
            else "deliveries per episode")
    for c in conds:
        levels = [0] + [lvl for cc, lvl, _ in sett if cc == c]
        head = " | ".join(["ideal"] + [f"{sev[(c, lvl)]:g}" for lvl in levels[1:]])
        key = lambda lvl, c=c: ("ideal", 0) if lvl == 0 else (c, lvl)  # noqa: E731
        lines += [f"### {c}: {what}, mean over seeds [95 % CI]", "",
                  f"| method | {head} |", "|---|" + "---|" * len(levels)]
        for m in names:
            lines.append(f"| {label(m)} | " + " | ".join(
                _fmt(est[m][key(lvl)], digits) for lvl in levels) + " |")
        lines.append("")
        if ratio_est:
            lines += [f"### {c}: makespan over the planner's (completed instances)", "",
                      f"| method | {head} |", "|---|" + "---|" * len(levels)]
            for m in names:
                lines.append(f"| {label(m)} | " + " | ".join(
                    _fmt(ratio_est[m][key(lvl)], 2) for lvl in levels) + " |")
            lines.append("")
        refs = [(m, reference(m, set(names))) for m in names]
        pairs = [(m, r) for m, r in refs if r is not None]
        if pairs:
            lines += [f"### {c}: P(SDHN > method) on {what} [95 % CI]", "",
                      f"| method (SDHN side) | {head} |", "|---|" + "---|" * len(levels)]
            for m, ref in pairs:
                cells = []
                for lvl in levels:
                    k = key(lvl)
                    x = [v for v in scores(methods[ref], metric)[k] if v is not None]
                    y = [v for v in scores(methods[m], metric)[k] if v is not None]
                    p = boot_poi(np.asarray(x)[:, None], np.asarray(y)[:, None])
                    js["poi"].setdefault(m, {"sdhn_side": ref})[f"{k[0]}/{k[1]}"] = p.to_json()
                    cells.append(p.fmt(2))
                lines.append(f"| {label(m)} ({label(ref)}) | " + " | ".join(cells) + " |")
            lines.append("")
    if "sdhn" in methods and SHR in methods:
        js["claim"] = claim_verdict(methods["sdhn"], methods[SHR], metric)
    return lines, js


def shipped_table(results: list[dict[str, Any]]) -> list[str]:
    rows = [r for r in results if "model" in r.get("source", {})]
    if not rows:
        return []
    out = ["## Shipped policies", "",
           "One actor each (no interval over seeds): success / makespan over the planner's, "
           "per setting.", ""]
    for r in sorted(rows, key=lambda r: r["key"]):
        out += [f"### {r['policy']} ({r['mode']}), {r.get('instances')} instances", "",
                "| condition | " + " | ".join(["ideal", "1", "2", "3", "4"]) + " |",
                "|---|---|---|---|---|---|"]
        by: dict[str, list[str]] = defaultdict(list)
        ideal = ""
        for s in r["settings"]:
            sm = s["summary"]
            cell = f"{sm['success_rate']:.2f} / " + (
                "—" if sm.get("makespan_over_planner") is None
                else f"{sm['makespan_over_planner']:.2f}")
            if s["level"] == 0:
                ideal = cell
            else:
                by[s["condition"]].append(f"{cell} (at {s['severity']:g})")
        for c, cells in by.items():
            out.append(f"| {c} | {ideal} | " + " | ".join(cells) + " |")
        out.append("")
    return out


def figure(task: str, methods: dict[str, list[dict[str, Any]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric = primary(task)
    any_runs = next(iter(methods.values()))
    sett = settings_of(any_runs)
    conds = list(dict.fromkeys(c for c, lvl, _ in sett if lvl > 0))
    sev = {(c, lvl): v for c, lvl, v in sett}
    rows = [(metric, "success" if metric == "success_rate" else "deliveries / episode")]
    if metric == "success_rate":
        rows.append(("makespan_over_planner", "makespan / planner's"))
    fig, axes = plt.subplots(len(rows), len(conds), figsize=(3.1 * len(conds), 2.7 * len(rows)),
                             squeeze=False, sharey="row")
    names = sorted(methods, key=lambda m: (m != "sdhn" and not m.startswith("sdhn_ent"), m))
    for j, c in enumerate(conds):
        levels = [0] + [lvl for cc, lvl, _ in sett if cc == c]
        for i, (met, ylabel) in enumerate(rows):
            ax = axes[i][j]
            for m in names:
                sc = scores(methods[m], met)
                pts = [(lvl, estimate(sc[("ideal", 0) if lvl == 0 else (c, lvl)])[0])
                       for lvl in levels]
                xs = [x for x, e in pts if e is not None]
                es = [e for _, e in pts if e is not None]
                if not es:
                    continue
                strong = m == "sdhn" or m.startswith("sdhn_ent") or m == SHR
                line = ax.plot(xs, [e.point for e in es], marker="o", ms=3,
                               lw=2.0 if strong else 1.0, label=label(m))[0]
                ax.fill_between(xs, [e.low for e in es], [e.high for e in es],
                                color=line.get_color(), alpha=0.15 if strong else 0.07, lw=0)
            ax.set_xticks(levels, ["0"] + [f"{sev[(c, lvl)]:g}" for lvl in levels[1:]],
                          fontsize=7)
            if i == 0:
                ax.set_title(c.replace("_", " "), fontsize=9)
            if i == len(rows) - 1:
                ax.set_xlabel("severity (0 = ideal)", fontsize=8)
            if j == 0:
                ax.set_ylabel(ylabel, fontsize=8)
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=6, loc="lower left")
    fig.suptitle(f"{task}: degradation under deployment conditions (mean over seeds, 95 % CI)",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def marl_eval(results: list[dict[str, Any]]) -> dict[str, Any]:
    runs: list[dict[str, Any]] = []
    for task, methods in by_method(results).items():
        maif = task.startswith("maif")
        for m, rs in methods.items():
            for r in rs:
                for s in r["settings"]:
                    name = f"{task}-{s['condition']}-{s['severity']:g}"
                    if maif:
                        recs = s["records"]
                        plan = r["planner_makespan"]
                        absolute = {"success_rate": [float(x[0]) for x in recs],
                                    "makespan_over_planner": [
                                        x[1] / p for x, p in zip(recs, plan, strict=True)
                                        if x[1] and p]}
                    else:
                        absolute = {"deliveries": [float(x) for x in s["records"]]}
                    runs.append({"env": "MAIF-conditions" if maif else "RWARE-conditions",
                                 "task": name, "algorithm": m, "run": str(r["seed"]),
                                 "steps": [], "absolute": absolute})
    return ps.marl_eval_json(runs)


def write_report(results: Path, outdir: Path) -> dict[str, Any]:
    res = load_results(results)
    outdir.mkdir(parents=True, exist_ok=True)
    tasks = by_method(res)
    lines = ["# Robustness under deployment conditions", "",
             "Generated by `robustness_suite report` from the per-actor results "
             "(`robustness_suite run`); the method is in "
             "[Deploying under real-world conditions](../../deploying-under-conditions.md).", ""]
    js: dict[str, Any] = {}
    cpu = [r["cpu_s"] for r in res]
    for task in sorted(tasks):
        t_lines, t_js = task_tables(task, tasks[task])
        lines += t_lines
        js[task] = t_js
        figure(task, tasks[task], outdir / f"robustness_{task}.png")
        lines += [f"![{task}](robustness_{task}.png)", ""]
        if "claim" in t_js and "p_smaller_loss_seeds" in t_js["claim"]:
            c = t_js["claim"]

            def est(j: dict[str, float]) -> str:
                return ps.Estimate(j["point"], j["ci95_low"], j["ci95_high"]).fmt(2)

            per = ", ".join(f"{k} {est(v)}" for k, v in
                            c["p_smaller_loss_per_condition"].items())
            lines += [f"**The uncertainty claim on {task}** (SDHN against SDHN w/o SHR, "
                      f"{c['seeds'][0]} and {c['seeds'][1]} seeds, {c['settings']} condition "
                      f"settings): mean success lost under the conditions "
                      f"{c['mean_loss_sdhn']:+.3f} against {c['mean_loss_other']:+.3f}; "
                      f"P(SDHN loses less) over seeds = {est(c['p_smaller_loss_seeds'])} "
                      f"(settings as tasks: {est(c['p_smaller_loss_settings_as_tasks'])}; per "
                      f"condition: {per}); P(SDHN scores higher under the conditions) = "
                      f"{est(c['p_better_under_conditions'])}: **{c['verdict']}**.", ""]
    lines += shipped_table(res)
    if cpu:
        lines += ["## Compute", "", "| task | actors | settings each | instances (episodes) | "
                  "CPU-s per actor-setting | CPU-s per actor | load (1 min) |",
                  "|---|---|---|---|---|---|---|"]
        for task in sorted({r["task"] for r in res}):
            rs = [r for r in res if r["task"] == task]
            per_setting = [r["cpu_s"] / len(r["settings"]) for r in rs]
            loads = [r.get("load_1min", 0.0) for r in rs]
            lines.append(f"| {task} | {len(rs)} | {len(rs[0]['settings'])} | "
                         f"{rs[0].get('instances', rs[0].get('episodes'))} | "
                         f"{np.mean(per_setting):.2f} | {np.mean([r['cpu_s'] for r in rs]):.0f} | "
                         f"{min(loads):.0f}-{max(loads):.0f} |")
        lines += ["", f"In all {sum(cpu) / 3600:.2f} CPU-hours for {len(res)} actor results.",
                  ""]
    (outdir / "robustness.md").write_text("\n".join(lines))
    write_json(outdir / "robustness.json", js)
    write_json(outdir / "marl_eval.json", marl_eval(res))
    return js
