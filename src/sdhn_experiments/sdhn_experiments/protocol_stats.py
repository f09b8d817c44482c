"""The statistics of the cooperative-MARL evaluation protocol (Gorsane et al., NeurIPS 2022),
computed with ``rliable`` (Agarwal et al.'s library, which that protocol and its ``marl-eval``
tool use): interquartile mean and mean with 95 % stratified bootstrap intervals, probability of
improvement, sample-efficiency curves; plus the ``marl-eval`` raw-data JSON.

Scores are arrays ``[runs, tasks]`` (one score per independent run and task; runs are seeds) or
``[runs, tasks, points]`` for curves. Bootstraps resample runs within each task (stratified).

    est = interval_estimates({"sdhn": x, "mappo": y})       # {"sdhn": Estimate(iqm, mean, ..)}
    poi = probability_of_improvement(x, y)                  # Estimate of P(X > Y)

``marl-eval`` itself is not a dependency: it pins pandas 1.4.4 (no build for Python 3.11 with
NumPy 2) and pulls neptune; its statistics are rliable's, and its input format is plain JSON,
written here by ``marl_eval_json``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from rliable import library as rly
from rliable import metrics

REPS = 5000
"""Bootstrap resamples (rliable's default is 50,000; 5,000 keeps the report in seconds and the
interval ends stable to ~0.005 on success rates)."""

FArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Estimate:
    point: float
    low: float
    high: float

    def fmt(self, digits: int = 2) -> str:
        return f"{self.point:.{digits}f} [{self.low:.{digits}f}, {self.high:.{digits}f}]"

    def to_json(self) -> dict[str, float]:
        return {"point": self.point, "ci95_low": self.low, "ci95_high": self.high}


def _bootstrap(data: dict[str, Any], func: Callable[..., FArray], reps: int,
               seed: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """rliable's ``get_interval_estimates`` (percentile intervals, 95 %), seeded. rliable hands
    arch a legacy RandomState, which arch 7 accepts with a FutureWarning: silenced here. Its
    stratified bootstraps draw their resamples from NumPy's global RNG (``np.random.choice`` in
    ``update_indices``), not from that RandomState, so the global RNG is seeded for the call and
    put back after it: the same scores give the same interval, whatever ran before."""
    saved = np.random.get_state()  # noqa: NPY002 (rliable's global RNG)
    np.random.seed(seed)  # noqa: NPY002 (rliable's global RNG)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            return rly.get_interval_estimates(data, func, reps=reps,
                                              random_state=np.random.RandomState(seed))
    finally:
        np.random.set_state(saved)  # noqa: NPY002 (rliable's global RNG)


def _scores(x: npt.ArrayLike) -> FArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]  # one task
    if a.ndim != 2 or a.shape[0] < 1:
        raise ValueError(f"scores must be [runs, tasks], got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("scores must be finite (a run without a score cannot be aggregated)")
    return a


def iqm(scores: npt.ArrayLike) -> float:
    """Interquartile mean over all runs and tasks (rliable's ``aggregate_iqm``)."""
    return float(metrics.aggregate_iqm(_scores(scores)))


def interval_estimates(groups: dict[str, npt.ArrayLike], reps: int = REPS,
                       seed: int = 0) -> dict[str, dict[str, Estimate]]:
    """{method: {"iqm": Estimate, "mean": Estimate}} with 95 % stratified bootstrap intervals."""
    data = {k: _scores(v) for k, v in groups.items()}

    def both(s: FArray) -> FArray:
        return np.array([metrics.aggregate_iqm(s), metrics.aggregate_mean(s)])

    out: dict[str, dict[str, Estimate]] = {}
    for k, s in data.items():
        if s.shape[0] == 1 or np.all(s == s[0]):  # one run (or no spread): no interval to draw
            p = both(s)
            out[k] = {"iqm": Estimate(float(p[0]), float(p[0]), float(p[0])),
                      "mean": Estimate(float(p[1]), float(p[1]), float(p[1]))}
            continue
        points, cis = _bootstrap({k: s}, both, reps, seed)
        p, ci = points[k], cis[k]
        out[k] = {"iqm": Estimate(float(p[0]), float(ci[0, 0]), float(ci[1, 0])),
                  "mean": Estimate(float(p[1]), float(ci[0, 1]), float(ci[1, 1]))}
    return out


def probability_of_improvement(x: npt.ArrayLike, y: npt.ArrayLike, reps: int = REPS,
                               seed: int = 0) -> Estimate:
    """P(X > Y): the chance that a run of X scores above a run of Y on a task (ties count a
    half; Mann-Whitney U / (n_x n_y)), averaged over tasks, with a 95 % interval from
    independent stratified bootstraps of both (rliable)."""
    sx, sy = _scores(x), _scores(y)
    if sx.shape[1] != sy.shape[1]:
        raise ValueError(f"X and Y must score the same tasks, got {sx.shape[1]} and {sy.shape[1]}")
    point = float(metrics.probability_of_improvement(sx, sy))
    if sx.shape[0] == 1 and sy.shape[0] == 1:
        return Estimate(point, point, point)
    _, cis = _bootstrap({"p": [sx, sy]},
                        lambda a, b: np.array([metrics.probability_of_improvement(a, b)]),
                        reps, seed)
    return Estimate(point, float(cis["p"][0, 0]), float(cis["p"][1, 0]))


def ratio_of_means(x: npt.ArrayLike, y: npt.ArrayLike, reps: int = REPS,
                   seed: int = 0) -> Estimate:
    """mean(X) / mean(Y) with a 95 % interval (independent stratified bootstraps): e.g. SDHN's
    makespan over MAPPO's (the paper claims 0.77)."""
    sx, sy = _scores(x), _scores(y)
    point = float(sx.mean() / sy.mean())
    if sx.shape[0] == 1 and sy.shape[0] == 1:
        return Estimate(point, point, point)
    _, cis = _bootstrap({"r": [sx, sy]}, lambda a, b: np.array([a.mean() / b.mean()]), reps,
                        seed)
    return Estimate(point, float(cis["r"][0, 0]), float(cis["r"][1, 0]))


def curve_estimates(curves: dict[str, npt.ArrayLike], reps: int = REPS,
                    seed: int = 0) -> dict[str, tuple[FArray, FArray, FArray]]:
    """Sample-efficiency curves: {method: (IQM [P], low [P], high [P])} from scores
    [runs, tasks, P] (P evaluation points shared by every run)."""
    out: dict[str, tuple[FArray, FArray, FArray]] = {}
    for k, c in curves.items():
        a = np.asarray(c, dtype=np.float64)
        if a.ndim == 2:
            a = a[:, None, :]
        if a.ndim != 3:
            raise ValueError(f"{k}: curves must be [runs, tasks, points], got {a.shape}")

        def per_point(s: FArray) -> FArray:
            return np.array([metrics.aggregate_iqm(s[..., t]) for t in range(s.shape[-1])])

        if a.shape[0] == 1:
            p = per_point(a)
            out[k] = (p, p.copy(), p.copy())
            continue
        points, cis = _bootstrap({k: a}, per_point, reps, seed)
        out[k] = (np.asarray(points[k]), np.asarray(cis[k][0]), np.asarray(cis[k][1]))
    return out


def marl_eval_json(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The raw-data JSON ``marl-eval`` reads::

        {env: {task: {algorithm: {run: {"step_<i>": {"step_count": int, metric: [..]},
                                        "absolute_metrics": {metric: [..]}}}}}}

    from ``runs``: dicts with ``env``, ``task``, ``algorithm``, ``run`` (e.g. the seed as a
    string), ``steps`` (a list of ``(step_count, {metric: [values]})``, in order) and
    ``absolute`` ({metric: [values]}; the final policy re-evaluated on the large held-out set).
    Algorithm names may not contain commas (marl-eval splits on them)."""
    out: dict[str, Any] = {}
    for r in runs:
        algo = str(r["algorithm"])
        if "," in algo:
            raise ValueError(f"algorithm {algo!r}: marl-eval names may not contain commas")
        entry: dict[str, Any] = {}
        for i, (count, values) in enumerate(r["steps"]):
            entry[f"step_{i}"] = {"step_count": int(count),
                                  **{m: [float(v) for v in vs] for m, vs in values.items()}}
        if r.get("absolute"):
            entry["absolute_metrics"] = {m: [float(v) for v in vs]
                                         for m, vs in r["absolute"].items()}
        tasks = out.setdefault(str(r["env"]), {}).setdefault(str(r["task"]), {})
        runs_of = tasks.setdefault(algo, {})
        key = str(r["run"])
        if key in runs_of:
            raise ValueError(f"{r['task']}/{algo}: run {key!r} given twice")
        runs_of[key] = entry
    return out
