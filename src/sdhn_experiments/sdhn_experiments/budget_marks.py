"""One long run judged at several budgets (issue 58): the absolute metric of the actors a MAIF
run exported at ``log.actor_marks`` (``actors/step_<mark>.safetensors``) and of its final actor,
each on the large held-out set in two modes:

- ``greedy``: argmax actions, the protocol's absolute metric;
- ``deployed``: the mode the task's shipped card deploys (``models/<task>-sdhn``: greedy with
  stall breaking for maif-10), applied to every run's actor, so the budgets are compared as
  the stack would run them.

Each result is cached beside its actor (``actors/step_<mark>.<mode>.json``: the summary and the
per-instance success and episode length, a few kB, carried with the run), so a suite's report is
recomputed from the logs alone and an actor is evaluated once. The final actor's greedy result
is the protocol's own cache (``heldout_large.json``), not a second one.

A mark counts for every run that has passed it, finished or not: at a mark the comparison rests
on the seeds that reached it (the tables say how many), and without ``MIN_VERDICT_SEEDS`` a side
it gives no verdict.
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_experiments import protocol_stats as ps
from sdhn_experiments.figures import Run
from sdhn_experiments.verdicts import makespan_verdict, too_few, verdict
from sdhn_train.run_files import read_run_text, run_file

MARKS_DIR = "actors"  # the trainer's ACTOR_MARKS_DIR (no torch import here)
MODES = ("greedy", "deployed")
SHIPPED = Path("models")
"""The shipped models whose cards name each task's deployment mode (the repository's, run from
its root; ``protocol_report --models`` names another)."""
_MARK_FILE = re.compile(r"^step_(\d+)\.safetensors$")


@dataclass(frozen=True)
class MarkResult:
    """One actor of one run, one mode, on the large held-out set."""

    run: str
    method: str
    seed: int
    mark: int
    mode: str
    success_rate: float
    makespan_ratio: float | None  # mean makespan over the planner's, own completions
    deadlocks_per_1000: float
    wanders_per_1000: float
    success: list[int]  # per instance, for marl-eval's absolute metrics
    length: list[int]


def marked_actors(run: Run) -> dict[int, Path]:
    """{mark: actor file}: the exported marks, and the final actor (at ``train.total_steps``)
    of a finished run."""
    out: dict[int, Path] = {}
    d = run.path / MARKS_DIR
    if d.is_dir():
        for f in d.iterdir():
            m = _MARK_FILE.match(f.name)
            if m and f.is_file():
                out[int(m.group(1))] = f
    final = run.path / "actor.safetensors"
    if (run.path / "DONE.json").is_file():
        out[int(run.config["train"]["total_steps"])] = final
    return dict(sorted(out.items()))


def cache_path(run: Run, mark: int, mode: str) -> Path:
    return run.path / MARKS_DIR / f"step_{mark}.{mode}.json"


def deploy_mode(task: str, models: Path = SHIPPED) -> dict[str, Any]:
    """evaluate_set's keyword arguments for the mode the task's shipped card deploys."""
    from sdhn_experiments.condition_eval import card_mode

    card = models / f"{task}-sdhn"
    if not (card / "card.json").is_file():
        raise ValueError(f"{task}: no shipped card at {card} to take the deployed mode from")
    mode = card_mode(card)
    return {"sample": not mode.greedy, "temperature": mode.temperature, "stall": mode.stall}


def _from_protocol_cache(run: Run) -> dict[str, Any] | None:
    """The protocol's greedy absolute metric of the final actor, in this module's shape."""
    f = run.path / "heldout_large.json"
    if not run_file(f).is_file():
        return None
    d = json.loads(read_run_text(f))
    return {"summary": d["summary"], "success": [int(r["success"]) for r in d["records"]],
            "length": [int(r["length"]) for r in d["records"]]}


def evaluate_mark(run: Run, mark: int, actor: Path, mode: str, *, planner_cache: Path | None,
                  compute: bool, models: Path = SHIPPED) -> MarkResult | None:
    """The cached result, or (``compute``) evaluate the actor and cache it; None: neither."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: allowed {', '.join(MODES)}")
    final = mark == int(run.config["train"]["total_steps"]) and actor.name == "actor.safetensors"
    cache = cache_path(run, mark, mode)
    data: dict[str, Any] | None = None
    if final and mode == "greedy":
        data = _from_protocol_cache(run)
    if data is None and cache.is_file():
        data = json.loads(cache.read_text())
    if data is None:
        if not compute or not actor.is_file():
            return None
        data = _evaluate(run, actor, mode, planner_cache, models)
        from sdhn_experiments.heldout_eval import write_json

        write_json(cache, data)
        print(f"[budget] {run.path.name} at {mark:,} ({mode}): success "
              f"{data['summary']['success_rate']:.3f}", flush=True)
    s = data["summary"]
    n = int(s["instances"])
    return MarkResult(run=run.path.name, method=run.method, seed=run.seed, mark=mark, mode=mode,
                      success_rate=float(s["success_rate"]),
                      makespan_ratio=s.get("makespan_ratio_mean"),
                      deadlocks_per_1000=1000 * s["failures"]["deadlock"] / n,
                      wanders_per_1000=1000 * s["failures"]["wander"] / n,
                      success=list(data["success"]), length=list(data["length"]))


def _evaluate(run: Run, actor: Path, mode: str, planner_cache: Path | None,
              models: Path) -> dict[str, Any]:
    from sdhn_experiments.heldout_eval import (
        evaluate_set,
        planner_makespans,
        set_checksum,
        set_instances,
        summarise,
    )
    from sdhn_policy.actor_runtime import ActorRuntime

    kwargs = deploy_mode(run.task, models) if mode == "deployed" else {}
    rt = ActorRuntime.from_file(actor)
    inst = set_instances(run.task, "heldout_large")
    recs = evaluate_set(rt, run.task, "heldout_large", reward=run.reward, **kwargs)
    plan = planner_makespans(run.task, "heldout_large", planner_cache)
    return {"set": "heldout_large", "set_checksum": set_checksum(inst), "mode": mode,
            "actor_sha256": _sha256(actor),
            "summary": summarise(recs, plan, inst.num_formations),
            "success": [int(r.success) for r in recs], "length": [int(r.length) for r in recs]}


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


MarkTable = dict[str, dict[int, dict[str, dict[str, list[MarkResult]]]]]
"""{task: {mark: {mode: {method: [results in seed order]}}}}"""


def collect(runs: list[Run], planner_cache: Path | None, compute: bool,
            models: Path = SHIPPED) -> MarkTable:
    """Every MAIF run's marked actors in both modes (runs without marks are left out)."""
    out: MarkTable = defaultdict(lambda: defaultdict(lambda: defaultdict(dict)))
    for r in sorted(runs, key=lambda r: (r.task, r.method, r.seed)):
        if not r.task.startswith("maif") or not (r.path / MARKS_DIR).is_dir():
            continue
        for mark, actor in marked_actors(r).items():
            for mode in MODES:
                res = evaluate_mark(r, mark, actor, mode, planner_cache=planner_cache,
                                    compute=compute, models=models)
                if res is not None:
                    out[r.task][mark][mode].setdefault(r.method, []).append(res)
    return out


def _budget(mark: int, seeds: int) -> str:
    return f"{mark / 1e6:g}M × {seeds} seed{'s' if seeds != 1 else ''}"


def _fmt(e: ps.Estimate, n: int, digits: int = 3) -> str:
    return f"{e.point:.{digits}f}" if n == 1 else e.fmt(digits)


def tables(marks: MarkTable, reps: int = ps.REPS) -> tuple[list[str], dict[str, Any]]:
    """The report's "by budget" section (markdown lines) and its JSON."""
    md = ["## By budget (the actors exported at `log.actor_marks` and the final one)", "",
          "Each run's actor at each mark on the 1,000-instance large held-out set: *greedy* "
          "(the protocol's absolute metric) and *deployed* (the shipped card's mode for the "
          "task, on every run's actor). Success IQM and mean over seeds with 95 % stratified "
          "bootstrap intervals; makespan over the planner's (mean over seeds of each run's mean "
          "over its completions); deadlocks and wanders per 1,000 episodes (means over seeds); "
          "P(SDHN > it) on success. A mark counts the seeds that reached it.", ""]
    js: dict[str, Any] = {}
    for task in sorted(marks):
        md += [f"### {task}", "",
               "| team steps | mode | method | seeds | success IQM | success mean | makespan / "
               "planner | deadlocks, wanders per 1,000 | P(SDHN > it) |",
               "|---|---|---|---|---|---|---|---|---|"]
        js[task] = {}
        for mark in sorted(marks[task]):
            for mode in MODES:
                by_method = marks[task][mark].get(mode, {})
                for method, res in sorted(by_method.items()):
                    scores = [r.success_rate for r in res]
                    est = ps.interval_estimates({method: scores}, reps)[method]
                    ratios = [r.makespan_ratio for r in res if r.makespan_ratio is not None]
                    poi = None
                    if method != "sdhn" and "sdhn" in by_method:
                        poi = ps.probability_of_improvement(
                            [r.success_rate for r in by_method["sdhn"]], scores, reps)
                    n = len(res)
                    md.append(
                        f"| {mark:,} | {mode} | {method} | {n} | {_fmt(est['iqm'], n)} | "
                        f"{_fmt(est['mean'], n)} | "
                        f"{f'{np.mean(ratios):.3f}' if ratios else '—'} | "
                        f"{np.mean([r.deadlocks_per_1000 for r in res]):.1f}, "
                        f"{np.mean([r.wanders_per_1000 for r in res]):.1f} | "
                        f"{'—' if poi is None else _fmt(poi, max(n, len(by_method['sdhn'])), 2)}"
                        " |")
                    js[task].setdefault(str(mark), {}).setdefault(mode, {})[method] = {
                        "seeds": [r.seed for r in res], "success": scores,
                        "makespan_ratio": [r.makespan_ratio for r in res],
                        "deadlocks_per_1000": [r.deadlocks_per_1000 for r in res],
                        "wanders_per_1000": [r.wanders_per_1000 for r in res],
                        "success_iqm": est["iqm"].to_json(), "success_mean": est["mean"].to_json(),
                        "poi_sdhn_over": None if poi is None else poi.to_json()}
        md.append("")
    return md, js


def claims_rows(marks: MarkTable, total_steps: dict[str, int],
                reps: int = ps.REPS) -> list[dict[str, str]]:
    """The headline claim (SDHN outperforms MAPPO; its makespan 23 % below) at each mark and
    mode. ``total_steps``: {task: the suite's final budget}; the final mark's greedy rows are
    the protocol's own and not repeated."""
    rows = []
    for task in sorted(marks):
        for mark in sorted(marks[task]):
            for mode in MODES:
                if mark == total_steps.get(task) and mode == "greedy":
                    continue
                ms = marks[task][mark].get(mode, {})
                if "sdhn" not in ms or "mappo" not in ms:
                    continue
                sd, mp = ms["sdhn"], ms["mappo"]
                few = too_few(len(sd), len(mp))
                at = f"at {mark / 1e6:g}M team steps, {mode}"
                poi = ps.probability_of_improvement([r.success_rate for r in sd],
                                                    [r.success_rate for r in mp], reps)
                n = max(len(sd), len(mp))
                rows.append({"claim": f"SDHN outperforms MAPPO on {task} ({at})",
                             "measurement": f"P(SDHN > MAPPO) = {_fmt(poi, n, 2)}"
                                            f" (success on the large held-out set, {len(sd)} vs "
                                            f"{len(mp)} seeds)",
                             "budget": _budget(mark, len(sd)),
                             "verdict": few or verdict(poi, 0.5)})
                sr = [r.makespan_ratio for r in sd if r.makespan_ratio is not None]
                mr = [r.makespan_ratio for r in mp if r.makespan_ratio is not None]
                if len(sr) == len(sd) and len(mr) == len(mp):
                    ratio = ps.ratio_of_means(sr, mr, reps)
                    v = few or makespan_verdict(ratio)
                    rows.append({"claim": f"SDHN's makespan is 23 % below MAPPO's on {task} "
                                          f"({at})",
                                 "measurement": "SDHN / MAPPO makespan (each over the planner's) "
                                                f"= {_fmt(ratio, max(len(sr), len(mr)), 3)}",
                                 "budget": _budget(mark, len(sd)), "verdict": v})
    return rows


def figure(marks: MarkTable, out: Path, reps: int = ps.REPS) -> Path | None:
    """Success against the budget, per method and mode, IQM with 95 % intervals."""
    if not marks:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted(marks)
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.5 * len(tasks), 3.6), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for mode, style in zip(MODES, ("-", "--"), strict=True):
            methods = sorted({m for mk in marks[task].values() for m in mk.get(mode, {})})
            for method in methods:
                xs, ys, lo, hi = [], [], [], []
                for mark in sorted(marks[task]):
                    res = marks[task][mark].get(mode, {}).get(method)
                    if not res:
                        continue
                    e = ps.interval_estimates({method: [r.success_rate for r in res]},
                                              reps)[method]["iqm"]
                    xs.append(mark / 1e6)
                    ys.append(e.point)
                    lo.append(e.low)
                    hi.append(e.high)
                ax.errorbar(xs, ys, yerr=[np.subtract(ys, lo), np.subtract(hi, ys)],
                            linestyle=style, marker="o", capsize=3, label=f"{method}, {mode}")
        ax.set_title(f"{task}: success on the large held-out set", fontsize=9)
        ax.set_xlabel("team env-steps (millions)")
        ax.set_ylabel("IQM over seeds, 95 % CI")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def marl_absolute(marks: MarkTable) -> list[dict[str, Any]]:
    """marl-eval runs, one per (method, seed, mark, mode): the algorithm is named
    ``<method>@<mark>_<mode>`` so marl-eval's tools compare budgets side by side."""
    out = []
    for task, by_mark in marks.items():
        for mark, by_mode in by_mark.items():
            for mode, by_method in by_mode.items():
                for method, res in by_method.items():
                    for r in res:
                        out.append({"env": "MAIF", "task": task,
                                    "algorithm": f"{method}@{mark}_{mode}",
                                    "run": str(r.seed), "steps": [],
                                    "absolute": {"success_rate": [float(x) for x in r.success],
                                                 "episode_length": [float(x) for x in
                                                                    r.length]}})
    return out
