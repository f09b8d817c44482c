"""Does training under randomised conditions help? Two arms of fine-tuned actors against the
policy they started from, under deployment conditions, in that policy's card mode.

    rows = evaluate_policies({"shipped": rt0, "control__s1": rt1, ...}, "maif-20", PLAN, mode)
    arms = compare_arms(rows, {"control": [...], "randomised": [...]}, baseline="shipped")

Every policy plays the same instances (``condition_eval.evaluate_under``: instance ``b`` in env
``b``, the condition model seeded ``seed``) under every condition of the plan. Per policy and
condition: success, makespan, and two paired makespan ratios per instance, over the instances
both complete: over the **policy's own** ideal-world makespan (the issue's goal) and over the
**baseline's** ideal-world makespan (a common yardstick, so a policy is not credited for an
ideal that got slower). Per arm (its seeds pooled): the mean of the per-instance ratios with a
95 % bootstrap interval over instances (each instance's seeds stay together), success with a
95 % bootstrap interval over maps, and the arm-minus-arm difference of the ratio, paired per
instance, with its interval.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from sdhn_experiments.condition_eval import (
    DEFAULT_SET,
    ConditionResult,
    Mode,
    evaluate_under,
    summarise_under,
)
from sdhn_experiments.heldout_eval import Policy, set_instances
from sdhn_sim.envs.conditions import Conditions

# (label, conditions, dead reckoning): the goals' conditions of issue 53 in the card's mode
PLAN: tuple[tuple[str, Conditions, bool], ...] = (
    ("ideal", Conditions(), False),
    ("latency 1, dead reckoning", Conditions(latency=1), True),
    ("lost actions 5 %", Conditions(lost_actions=0.05), False),
    ("half the team at half rate", Conditions(slow_fraction=0.5, slow_rate=0.5), False),
)


def evaluate_policies(policies: Mapping[str, Policy], task: str,
                      plan: Sequence[tuple[str, Conditions, bool]], mode: Mode, *,
                      instances: int, which: str = DEFAULT_SET, seed: int = 0,
                      log: Any = None) -> dict[str, dict[str, list[ConditionResult]]]:
    """{policy: {condition label: per-instance results}}; the plan's first row is the ideal."""
    out: dict[str, dict[str, list[ConditionResult]]] = {}
    for name, policy in policies.items():
        out[name] = {}
        for label, cond, dr in plan:
            out[name][label] = evaluate_under(policy, task, cond, replace(mode, dead_reckon=dr),
                                              instances=instances, which=which, seed=seed)
            if log is not None:
                s = summarise_under(out[name][label], None, 5)
                log(f"[pilot] {name} {label}: success {s['success_rate']:.3f}, makespan "
                    f"{s['makespan_mean']}")
    return out


def ratios(recs: Sequence[ConditionResult], ideal: Sequence[ConditionResult]
           ) -> list[float | None]:
    """Per instance: makespan under the condition over ``ideal``'s (None unless both done)."""
    return [r.makespan / i.makespan if r.makespan is not None and i.makespan else None
            for r, i in zip(recs, ideal, strict=True)]


def _boot(x: np.ndarray, stat: Any, seed: int = 0, resamples: int = 5000
          ) -> tuple[float, float]:
    """Percentile bootstrap interval of ``stat`` over the rows of ``x`` (instances)."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(x), size=(resamples, len(x)))
    vals = np.array([stat(x[i]) for i in idx])
    vals = vals[np.isfinite(vals)]
    return float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))


def _nanmean_all(a: np.ndarray) -> float:
    return float(np.nanmean(a)) if np.isfinite(a).any() else float("nan")


def arm_figures(rows: Mapping[str, Mapping[str, list[ConditionResult]]], members: list[str],
                label: str, ideal_label: str, baseline: str) -> dict[str, Any]:
    """One arm (its seeds pooled) under one condition; see the module docstring."""
    own = np.array([[np.nan if v is None else v for v in
                     ratios(rows[m][label], rows[m][ideal_label])] for m in members]).T
    base = np.array([[np.nan if v is None else v for v in
                      ratios(rows[m][label], rows[baseline][ideal_label])] for m in members]).T
    success = np.array([[r.success for r in rows[m][label]] for m in members], dtype=float).T
    maps = np.array([r.map for r in rows[members[0]][label]])
    per_map = np.array([success[maps == k].mean(axis=0) for k in np.unique(maps)])  # [M, S]
    mk = [r.makespan for m in members for r in rows[m][label] if r.makespan is not None]
    out: dict[str, Any] = {
        "seeds": len(members), "instances": int(success.shape[0]),
        "success_rate": float(success.mean()),
        "success_per_seed": [float(x) for x in success.mean(axis=0)],
        "success_ci95_maps": _boot(per_map, lambda x: float(x.mean()))
        if np.ptp(per_map) > 0 else (float(per_map.mean()),) * 2,
        "makespan_mean": float(np.mean(mk)) if mk else None,
    }
    for key, a in (("over_own_ideal", own), ("over_baseline_ideal", base)):
        out[f"makespan_{key}"] = _nanmean_all(a)
        out[f"makespan_{key}_per_seed"] = [
            float(np.nanmean(a[:, s])) if np.isfinite(a[:, s]).any() else None
            for s in range(a.shape[1])]
        out[f"makespan_{key}_ci95"] = _boot(a, _nanmean_all)
        out[f"makespan_{key}_pairs"] = int(np.isfinite(a).sum())
    return out


def arm_difference(rows: Mapping[str, Mapping[str, list[ConditionResult]]], arm: list[str],
                   other: list[str], *, label: str, ideal_label: str, key: str,
                   baseline: str) -> dict[str, Any]:
    """Arm minus other arm of the per-instance makespan ratio (``key``: own or baseline ideal),
    each instance's ratio first averaged over the arm's seeds; paired per instance."""
    def per_instance(members: list[str]) -> np.ndarray:
        a = np.array([[np.nan if v is None else v for v in ratios(
            rows[m][label], rows[m if key == "own" else baseline][ideal_label])]
            for m in members])
        with warnings.catch_warnings():  # an instance no seed completes: NaN, skipped below
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmean(a, axis=0)

    d = per_instance(arm) - per_instance(other)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"mean": None, "ci95": None, "instances": 0}
    return {"mean": float(d.mean()), "ci95": _boot(d, lambda x: float(x.mean())),
            "instances": int(d.size)}


def compare_arms(rows: Mapping[str, Mapping[str, list[ConditionResult]]],
                 arms: Mapping[str, list[str]], baseline: str,
                 plan: Sequence[tuple[str, Conditions, bool]] = PLAN) -> dict[str, Any]:
    """{condition: {arm: figures, ..., "difference": {arm: vs first arm}}} for the arms and
    the baseline (an arm of one)."""
    ideal = plan[0][0]
    names = list(arms)
    out: dict[str, Any] = {}
    for label, _, _ in plan:
        row: dict[str, Any] = {baseline: arm_figures(rows, [baseline], label, ideal, baseline)}
        for arm, members in arms.items():
            row[arm] = arm_figures(rows, members, label, ideal, baseline)
        row["difference"] = {
            f"{arm} - {names[0]}": {
                key: arm_difference(rows, arms[arm], arms[names[0]], label=label,
                                    ideal_label=ideal, key=key, baseline=baseline)
                for key in ("own", "baseline")}
            for arm in names[1:]}
        out[label] = row
    return out


def markdown(table: Mapping[str, Any], arms: Sequence[str], baseline: str) -> str:
    """Success and makespan over the own and over the baseline's ideal, per condition."""
    def cell(f: Mapping[str, Any]) -> str:
        o, b = f["makespan_over_own_ideal"], f["makespan_over_baseline_ideal"]
        lo, hi = f["makespan_over_own_ideal_ci95"]
        return (f"{f['success_rate']:.2f} / {o:.2f}× [{lo:.2f}, {hi:.2f}] / {b:.2f}×"
                if np.isfinite(o) else f"{f['success_rate']:.2f} / NC")
    cols = [baseline, *arms]
    lines = ["| condition | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for label, row in table.items():
        lines.append(f"| {label} | " + " | ".join(cell(row[c]) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def instances_of(task: str, which: str = DEFAULT_SET) -> int:
    return set_instances(task, which).num_instances
