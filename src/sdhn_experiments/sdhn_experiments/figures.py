"""Figures and tables of the paper's experiments, from run logs only (the trainer writes the P_H
snapshots, ``sdhn_train.runs.save_ph_snapshot``; this module only reads and plots them).

    make_figures LOGDIR OUTDIR          (scripts/make_figures.py)

LOGDIR holds run directories (``<run>/config.yaml`` + ``<run>/metrics.csv`` from the trainer;
``run.json`` from the experiment runner when present, ``hypergraph/ph_*.npz`` from SDHN runs).
A run's method label is ``run.json``'s, else derived from its config (``sdhn_wo_lsk`` =
sdhn with ``sdhn.skew_loss: false``, ``sdhn_wo_shr`` = with ``sdhn.stochastic_hyperedges: false``).
Written to OUTDIR (a figure whose data are absent is skipped and listed in results.md):

- ``success.png`` (MAIF): greedy success rate on the training and the held-out instances over
  training, per method, with the scripted baselines' success as horizontal lines;
- ``returns.png``: training return (``charts/episodic_return``, under the reward named on the
  axis) per task, mean and +-1 std over seeds per method (paper Fig. "Performance of SDHN and
  baselines");
- ``makespan.png``: final greedy makespan vs robot count on MAIF, NC where no seed completed, with
  the scripted planner's and greedy policy's makespan marked;
- ``ablation_<task>.png``: SDHN vs w/o L_Sk and vs w/o stochastic hyperedges;
- ``ph_heatmap_<task>.png``: P_H (N x M) of SDHN trained with and without L_Sk;
- ``skewness.png``: Sk of the sampled hypergraphs (``hypergraph/skewness``) over training;
- ``results.md``: per task x method, final greedy success rate and makespan on the training and
  the held-out instances first, then return under the reward named; on MAIF the scripted
  baselines (``sdhn_sim.envs.maif_scripted``, evaluated here on the runs' evaluation instances)
  are rows of the table.
- ``scripted.json``: those baselines' results, reused by the next call on the same OUTDIR (delete
  it after changing the scripted policies).
Refuses (FigureError) a LOGDIR that is empty, holds something that is not a run, names one
(task, method, seed) twice, or mixes budgets or suites within a task.
"""

from __future__ import annotations

import json
import zipfile
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_sim.envs.maif_scripted import SCRIPTED_LABELS, ScriptedResult, evaluate_scripted
from sdhn_sim.envs.registry import env_names
from sdhn_train import metrics_file
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.runs import PH_DIR

# --- reading runs -----------------------------------------------------------------------------

ABLATIONS = ("sdhn_wo_lsk", "sdhn_wo_shr")  # method labels of SDHN runs with an ablation set


def task_order() -> tuple[str, ...]:
    """Plot order of tasks: the env registry's."""
    return tuple(env_names())


def method_order() -> tuple[str, ...]:
    """Plot order of methods: the algorithm registry's, then SDHN's ablations."""
    return (*ALGO_NAMES, *ABLATIONS)


METHOD_LABEL = {"sdhn": "SDHN", "mappo": "MAPPO", "qmix": "QMIX", "dicg": "DICG",
                "hgcn_mix": "HGCN-MIX", "sdhn_wo_lsk": "SDHN w/o $L_{Sk}$",
                "sdhn_wo_shr": "SDHN w/o SHR",
                # the variants the shipped suites (configs/suites/*-warm.yaml) name
                "sdhn_lambda_sk_pos": "SDHN, λ_Sk = +0.6",
                "sdhn_generator_1_layer": "SDHN, 1-layer generator",
                "sdhn_2_epochs": "SDHN, 2 PPO epochs"}
BUDGET_KEYS = (("train", "total_steps"), ("env", "max_steps"), ("env", "reward"))
SETS = (("", "train"), ("heldout_", "heldout"))  # (metric tag infix, instance set)
SCRIPTED_CACHE = "scripted.json"  # in OUTDIR: the scripted baselines' results, kept across runs


class FigureError(ValueError):
    """A log directory the figures cannot honestly be drawn from."""


Series = metrics_file.Series  # (steps, values), sorted by step


@dataclass
class Run:
    path: Path
    task: str
    method: str
    seed: int
    config: dict[str, Any]
    suite: str | None
    series: dict[str, Series] = field(default_factory=dict)

    def final(self, tag: str) -> float | None:
        s = self.series.get(tag)
        return float(s[1][-1]) if s is not None and len(s[0]) else None

    def value_at(self, tag: str, step: int) -> float | None:
        """``tag``'s value at ``step`` or the last one logged before it (None: nothing by then)."""
        s = self.series.get(tag)
        if s is None:
            return None
        k = int(np.searchsorted(s[0], step, side="right")) - 1
        return float(s[1][k]) if k >= 0 else None

    @property
    def reward(self) -> str:
        """The reward the run was trained and evaluated with (MAIF names two; RWARE has one)."""
        if self.task.startswith("maif"):
            return str(self.config["env"].get("reward", "corrected"))
        return "rware"

    def final_eval_step(self) -> int | None:
        s = self.series.get("eval/episodic_return")
        return int(s[0][-1]) if s is not None and len(s[0]) else None


def method_of(config: dict[str, Any]) -> str:
    algo = str(config["algo"]["name"])
    if algo == "sdhn":
        if not config["sdhn"].get("skew_loss", True):
            return "sdhn_wo_lsk"
        if not config["sdhn"].get("stochastic_hyperedges", True):
            return "sdhn_wo_shr"
    return algo


def read_metrics(path: Path) -> dict[str, Series]:
    """{tag: (steps, values)} from a run's metrics file, through the one reader
    (:func:`sdhn_train.metrics_file.read_series`); a damaged file is a FigureError naming the
    file and line."""
    try:
        return metrics_file.read_series(path)
    except metrics_file.MetricsFileError as e:
        raise FigureError(str(e)) from None


def _read_config(path: Path) -> dict[str, Any]:
    """A run's config.yaml as written by the trainer; FigureError (one line) otherwise."""
    try:
        config = load_yaml(path, what="run config")
    except YamlError as e:
        raise FigureError(str(e)) from None
    if not isinstance(config, dict):
        raise FigureError(f"{path}: not a trainer config (expected a mapping of sections, got "
                          f"{type(config).__name__})")
    for section in ("env", "algo", "train"):
        if not isinstance(config.get(section), dict):
            raise FigureError(f"{path}: not a trainer config (section {section!r} missing)")
    if "name" not in config["env"] or "name" not in config["algo"]:
        raise FigureError(f"{path}: not a trainer config (env.name or algo.name missing)")
    for section in ("sdhn", "eval"):
        if not isinstance(config.setdefault(section, {}), dict):
            raise FigureError(f"{path}: section {section!r} is not a mapping")
    return config


def _read_spec(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {}
    try:
        spec = json.loads(path.read_bytes())
    except (OSError, ValueError) as e:
        raise FigureError(f"{path}: unreadable run spec ({type(e).__name__})") from None
    if not isinstance(spec, dict):
        raise FigureError(f"{path}: not a run spec (expected a JSON object)")
    return spec


def read_run(path: Path) -> Run:
    cfg_file, csv_file = path / "config.yaml", metrics_file.metrics_path(path)
    missing = [f.name for f in (cfg_file, csv_file) if not f.is_file()]
    if missing:
        raise FigureError(f"{path} is not a finished trainer run (missing {', '.join(missing)})")
    config = _read_config(cfg_file)
    spec = _read_spec(path / "run.json")
    try:
        seed = int(spec.get("seed", config["train"].get("seed")))
    except (TypeError, ValueError):
        raise FigureError(f"{path}: no integer seed in run.json or config.yaml") from None
    task = str(spec.get("task", config["env"]["name"]))
    if task not in env_names():
        raise FigureError(f"{path}: task {task!r} is not an environment; allowed: "
                          f"{', '.join(env_names())}")
    return Run(path=path, task=task,
               method=str(spec.get("method", method_of(config))),
               seed=seed, config=config,
               suite=spec.get("suite"), series=read_metrics(csv_file))


def _just_created(run: Path) -> bool:
    """A run directory the experiment runner has made (its ``run.json``) whose trainer has not
    yet written its config or metrics: what a report run beside a suite sees for a moment."""
    return ((run / "run.json").is_file() and not (run / "config.yaml").exists()
            and not metrics_file.metrics_path(run).exists())


def load_runs(logdir: Path) -> list[Run]:
    """Every run directly under ``logdir`` (but one just created, see ``_just_created``);
    FigureError if it is empty or mixed up."""
    if not logdir.is_dir():
        raise FigureError(f"{logdir} is not a directory")
    entries = sorted(p for p in logdir.iterdir() if not p.name.startswith("."))
    if not entries:
        raise FigureError(f"{logdir} is empty: expected run directories (<run>/metrics.csv and "
                          "<run>/config.yaml, as written by train or run_experiments)")
    strays = [p.name for p in entries if not p.is_dir()]
    if strays:
        raise FigureError(f"{logdir} mixes runs with other files ({', '.join(strays[:5])}): "
                          "point make_figures at a directory holding only run directories")
    runs = [read_run(p) for p in entries if not _just_created(p)]
    if not runs:
        raise FigureError(f"{logdir}: no run has started writing yet (every run directory "
                          "holds only the runner's run.json)")
    seen: dict[tuple[str, str, int], Path] = {}
    for r in runs:
        key = (r.task, r.method, r.seed)
        if key in seen:
            raise FigureError(f"{seen[key].name} and {r.path.name} are both {r.method} on "
                              f"{r.task} with seed {r.seed}: mixed-up log directory")
        seen[key] = r.path
    suites = {r.suite for r in runs if r.suite is not None}
    if len(suites) > 1:
        raise FigureError(f"{logdir} mixes suites {sorted(suites)}")
    by_task: dict[str, dict[tuple[Any, ...], list[str]]] = defaultdict(lambda: defaultdict(list))
    for r in runs:
        budget = tuple(r.config[a].get(b) for a, b in BUDGET_KEYS)
        by_task[r.task][budget].append(r.path.name)
    for task, budgets in by_task.items():
        if len(budgets) > 1:
            desc = "; ".join(f"{dict(zip([k for _, k in BUDGET_KEYS], b, strict=True))}: "
                             f"{', '.join(names[:3])}" for b, names in budgets.items())
            raise FigureError(f"{logdir} mixes budgets on {task}: {desc}")
    return runs


def _ordered(keys: Any, order: tuple[str, ...]) -> list[str]:
    keys = set(keys)
    return [k for k in order if k in keys] + sorted(keys - set(order))


def seed_curves(runs: list[Run], tag: str, points: int = 100,
                smooth: int = 5) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-seed curves of ``tag`` on a common step grid: (grid [P], values [seeds, P]); a
    trailing moving average of ``smooth`` logged points first."""
    curves = [r.series[tag] for r in runs if tag in r.series and len(r.series[tag][0])]
    if not curves:
        return None
    end = min(int(s[-1]) for s, _ in curves)
    start = max(int(s[0]) for s, _ in curves)
    grid = np.linspace(start, max(end, start), points)
    out = []
    for steps, vals in curves:
        k = max(1, min(smooth, len(vals)))
        sm = np.convolve(vals, np.ones(k) / k, mode="full")[: len(vals)]
        sm[: k - 1] = np.cumsum(vals[: k - 1]) / np.arange(1, k)
        out.append(np.interp(grid, steps, sm))
    return grid, np.array(out)


Scripted = dict[str, dict[tuple[str, str], ScriptedResult]]  # task -> (policy, set) -> result


def scripted_baselines(runs: list[Run], instances: int | None = None,
                       cache: Path | None = None) -> Scripted:
    """The scripted greedy policy and planner on every MAIF task of ``runs``, on the instances,
    seed and reward the runs were evaluated with (``instances`` overrides the count). They are
    deterministic, and the planner takes minutes on the larger teams, so results are kept in
    ``cache`` (JSON, keyed by everything they depend on) across calls."""
    known = _read_cache(cache) if cache is not None else {}
    out: Scripted = {}
    for task, group in _by(runs, "task").items():
        if not task.startswith("maif"):
            continue
        k = instances or min(int(r.config.get("eval", {}).get("instances", 100)) for r in group)
        seed = int(group[0].config.get("eval", {}).get("seed", 0))
        out[task] = {}
        for policy in SCRIPTED_LABELS:
            for _, which in SETS:
                key = f"{task}/{which}/{policy}/k={k}/seed={seed}/{group[0].reward}"
                result = _cached_result(known.get(key))
                if result is None:
                    result = evaluate_scripted(task, which, policy, instances=k, seed=seed,
                                               reward=group[0].reward)
                    known[key] = asdict(result)
                out[task][(policy, which)] = result
    if cache is not None:
        tmp = cache.with_suffix(".tmp")
        tmp.write_text(json.dumps(known, indent=1, sort_keys=True))
        tmp.replace(cache)
    return out


def _read_cache(cache: Path) -> dict[str, Any]:
    """The scripted baselines' cache; an unreadable one is ignored (it is recomputed and
    rewritten: it only saves time)."""
    if not cache.is_file():
        return {}
    try:
        known = json.loads(cache.read_bytes())
    except (OSError, ValueError):
        return {}
    return known if isinstance(known, dict) else {}


def _cached_result(entry: Any) -> ScriptedResult | None:
    """A cache entry as a ScriptedResult, or None if it is not one (recomputed)."""
    if not isinstance(entry, dict):
        return None
    try:
        result = ScriptedResult(**entry)
    except TypeError:
        return None
    numbers = (result.success_rate, result.episode_return, result.collisions, result.lower_bound)
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in numbers):
        return None
    if result.makespan is not None and not isinstance(result.makespan, int | float):
        return None
    return result


# --- figures ----------------------------------------------------------------------------------


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _grid(n: int, width: float = 4.2, height: float = 3.2) -> tuple[Any, list[Any]]:
    plt = _plt()
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(width * cols, height * rows), squeeze=False)
    flat = list(axes.flat)
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def _save(fig: Any, path: Path) -> Path:
    """Write ``fig`` to ``path`` at the figures' resolution and free it (pyplot keeps every
    figure open until it is closed)."""
    fig.savefig(path, dpi=120)
    _plt().close(fig)
    return path


def _curves(ax: Any, groups: dict[str, list[Run]], tag: str, title: str, *,
            smooth: int = 5, legend: bool = True) -> None:
    for method in _ordered(groups, method_order()):
        got = seed_curves(groups[method], tag, smooth=smooth)
        if got is None:
            continue
        grid, vals = got
        mean, std = vals.mean(0), vals.std(0)
        line = ax.plot(grid, mean, label=f"{METHOD_LABEL.get(method, method)} (n={len(vals)})")
        ax.fill_between(grid, mean - std, mean + std, alpha=0.2, color=line[0].get_color())
    ax.set_title(title)
    ax.set_xlabel("team env-steps")
    ax.grid(alpha=0.3)
    if legend:
        ax.legend(fontsize=7)


def _by(runs: list[Run], *attrs: str) -> dict[Any, list[Run]]:
    out: dict[Any, list[Run]] = defaultdict(list)
    for r in runs:
        key = tuple(getattr(r, a) for a in attrs)
        out[key[0] if len(key) == 1 else key].append(r)
    return out


def fig_success(runs: list[Run], out: Path, scripted: Scripted) -> Path | None:
    """Greedy success rate over training on the training (top) and held-out (bottom) instances,
    per MAIF task, with the scripted baselines as horizontal lines."""
    maif = [r for r in runs if "eval/success_rate" in r.series and r.task.startswith("maif")]
    tasks = _ordered(_by(maif, "task"), task_order())
    if not tasks:
        return None
    plt = _plt()
    fig, axes = plt.subplots(2, len(tasks), figsize=(4.6 * len(tasks) + 2.0, 6.4), squeeze=False)
    for col, task in enumerate(tasks):
        group = _by([r for r in maif if r.task == task], "method")
        for row, (infix, which) in enumerate(SETS):
            ax = axes[row][col]
            # Each point is already a mean over the evaluation instances: not smoothed, so the
            # last point is the final evaluation the table reports.
            _curves(ax, group, f"eval/{infix}success_rate",
                    f"{task}: {'held-out' if infix else 'training'} instances", smooth=1,
                    legend=False)
            for policy, style in (("planner", "--"), ("greedy", ":")):
                res = scripted.get(task, {}).get((policy, which))
                if res is not None:
                    ax.axhline(res.success_rate, color="k", lw=1.0, ls=style,
                               label=SCRIPTED_LABELS[policy])
            ax.set_ylim(-0.03, 1.03)
            ax.set_ylabel(f"greedy success rate ({group[next(iter(group))][0].reward} reward)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=7)
    fig.tight_layout(rect=(0.0, 0.0, 0.7, 1.0))
    return _save(fig, out / "success.png")


def fig_returns(runs: list[Run], out: Path) -> Path | None:
    main = [r for r in runs if r.method not in ABLATIONS]
    tasks = _ordered(_by(main, "task"), task_order())
    if not tasks:
        return None
    fig, axes = _grid(len(tasks))
    for ax, task in zip(axes, tasks, strict=True):
        group = [r for r in main if r.task == task]
        _curves(ax, _by(group, "method"), "charts/episodic_return", task)
        ax.set_ylabel(f"episode return ({group[0].reward} reward)")
    fig.tight_layout()
    return _save(fig, out / "returns.png")


def lambda_sk(run: Run) -> float | None:
    """The run's target skewness lambda_Sk, from its own config (None if it has none)."""
    value = run.config.get("sdhn", {}).get("lambda_sk")
    return float(value) if value is not None else None


def num_robots(run: Run) -> int:
    from sdhn_sim.envs import MAIF_CONFIGS

    return MAIF_CONFIGS[run.task].num_robots


def final_makespan(runs: list[Run], infix: str = "") -> tuple[float | None, list[float]]:
    """(mean makespan over seeds whose final greedy evaluation completed any episode, or None =
    NC; the per-seed values) on the training (``infix`` "") or held-out ("heldout_") instances.
    Falls back to training episodes where a run has no evaluation (training set only)."""
    vals = []
    for r in runs:
        prefix = "eval" if r.final_eval_step() is not None else "charts"
        if prefix == "charts" and infix:
            continue
        succ = r.final(f"{prefix}/{infix}success_rate")
        ms = r.series.get(f"{prefix}/{infix}makespan")
        if succ and ms is not None and len(ms[0]):
            vals.append(float(ms[1][-1]))
    return (float(np.mean(vals)) if vals else None), vals


def fig_makespan(runs: list[Run], out: Path, scripted: Scripted) -> Path | None:
    maif = [r for r in runs if r.task.startswith("maif-") and r.task != "maif-tiny"
            and r.method not in ABLATIONS]
    if not maif:
        maif = [r for r in runs if r.task.startswith("maif-")
                and r.method not in ABLATIONS]
    if not maif:
        return None
    plt = _plt()
    tasks = sorted(_by(maif, "task"), key=lambda t: num_robots(_by(maif, "task")[t][0]))
    methods = _ordered(_by(maif, "method"), method_order())
    fig, ax = plt.subplots(figsize=(3.6 + 1.4 * len(tasks) * max(1, len(methods)) / 3, 3.4))
    width = 0.8 / len(methods)
    tops = []
    for j, method in enumerate(methods):
        for i, task in enumerate(tasks):
            group = [r for r in maif if r.task == task and r.method == method]
            if not group:
                continue
            mean, vals = final_makespan(group)
            x = i + (j - (len(methods) - 1) / 2) * width
            if mean is None:
                ax.text(x, 0, "NC", ha="center", va="bottom", fontsize=7, rotation=90,
                        color=f"C{j}")
                continue
            ax.bar(x, mean, width, color=f"C{j}", yerr=np.std(vals) if len(vals) > 1 else None,
                   label=METHOD_LABEL.get(method, method) if i == 0 or not ax.patches else None)
            tops.append(mean)
    handles = [plt.Rectangle((0, 0), 1, 1, color=f"C{j}") for j in range(len(methods))]
    labels = [METHOD_LABEL.get(m, m) for m in methods]
    for policy, style in (("planner", "--"), ("greedy", ":")):
        for i, task in enumerate(tasks):  # the training set's, as the bars
            res = scripted.get(task, {}).get((policy, "train"))
            if res is not None and res.makespan is not None:
                line = ax.hlines(res.makespan, i - 0.45, i + 0.45, colors="k", lw=1.2,
                                 linestyles=style)
        if any((policy, "train") in scripted.get(t, {}) for t in tasks):
            handles.append(line)
            labels.append(SCRIPTED_LABELS[policy])
    ax.legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_xticks(range(len(tasks)),
                  [f"{num_robots(_by(maif, 'task')[t][0])} robots" for t in tasks])
    ax.set_ylabel("makespan (steps; NC = not completed)")
    ax.set_title("Average makespan on MAIF (final greedy evaluation)")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, out / "makespan.png")


def fig_ablations(runs: list[Run], out: Path) -> list[Path]:
    paths = []
    for task in _ordered(_by(runs, "task"), task_order()):
        group = _by([r for r in runs if r.task == task], "method")
        panels = [(abl, title) for abl, title in (("sdhn_wo_lsk", "with / without $L_{Sk}$"),
                                                  ("sdhn_wo_shr", "with / without SHR"))
                  if abl in group and "sdhn" in group]
        if not panels:
            continue
        fig, axes = _grid(len(panels))
        for ax, (abl, title) in zip(axes, panels, strict=True):
            _curves(ax, {"sdhn": group["sdhn"], abl: group[abl]}, "charts/episodic_return",
                    f"{task}: {title}")
            ax.set_ylabel(f"episode return ({group['sdhn'][0].reward} reward)")
        fig.tight_layout()
        paths.append(_save(fig, out / f"ablation_{task}.png"))
    return paths


def latest_ph(run: Run) -> tuple[int, np.ndarray] | None:
    snaps = sorted((run.path / PH_DIR).glob("ph_*.npz"))
    if not snaps:
        return None
    try:
        with np.load(snaps[-1], allow_pickle=False) as z:
            step, ph = int(z["step"]), np.array(z["ph_last"], dtype=float)
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as e:
        raise FigureError(f"{snaps[-1]}: not a P_H snapshot ({type(e).__name__}); delete it "
                          "to draw the heatmap from the one before") from None
    if ph.ndim != 2 or not np.isfinite(ph).all():
        raise FigureError(f"{snaps[-1]}: ph_last is not a finite N x M matrix "
                          f"(shape {ph.shape}); delete it to use the one before")
    return step, ph


def fig_ph_heatmaps(runs: list[Run], out: Path) -> list[Path]:
    paths = []
    plt = _plt()
    for task in _ordered(_by(runs, "task"), task_order()):
        found = {}
        for method in ("sdhn_wo_lsk", "sdhn"):
            cands = sorted((r for r in runs if r.task == task and r.method == method),
                           key=lambda r: r.seed)
            for r in cands:
                snap = latest_ph(r)
                if snap is not None:
                    found[method] = (r, *snap)
                    break
        if len(found) < 2:
            continue
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
        im = None
        for ax, method in zip(axes, ("sdhn_wo_lsk", "sdhn"), strict=True):
            run, step, ph = found[method]
            im = ax.imshow(ph, vmin=0.0, vmax=1.0, cmap="viridis", aspect="auto")
            ax.set_title(f"{METHOD_LABEL[method] if method != 'sdhn' else 'SDHN (with $L_{Sk}$)'}"
                         f"\nseed {run.seed}, step {step}, mean p {ph.mean():.2f}", fontsize=9)
            ax.set_xlabel("hyperedge j")
            ax.set_ylabel("robot i")
        fig.colorbar(im, ax=list(axes), label="$P_H$")
        paths.append(_save(fig, out / f"ph_heatmap_{task}.png"))
    return paths


def fig_skewness(runs: list[Run], out: Path) -> Path | None:
    sk = [r for r in runs if "hypergraph/skewness" in r.series]
    tasks = _ordered(_by(sk, "task"), task_order())
    if not tasks:
        return None
    fig, axes = _grid(len(tasks))
    for ax, task in zip(axes, tasks, strict=True):
        _curves(ax, _by([r for r in sk if r.task == task], "method"), "hypergraph/skewness",
                f"{task}: skewness of sampled H")
        targets = sorted({t for r in sk if r.task == task and r.method != "sdhn_wo_lsk"
                          and (t := lambda_sk(r)) is not None})
        for target in targets:
            ax.axhline(target, color="k", lw=0.8, ls="--")
        shown = ", ".join(f"{t:g}" for t in targets) or "none"
        ax.set_ylabel(f"Sk (target $\\lambda_{{Sk}}$ = {shown})")
    fig.tight_layout()
    return _save(fig, out / "skewness.png")


def _fmt(vals: list[float], digits: int = 1) -> str:
    if not vals:
        return "-"
    if len(vals) == 1:
        return f"{vals[0]:.{digits}f}"
    return f"{np.mean(vals):.{digits}f} ± {np.std(vals):.{digits}f}"


def _ms(mean: float | None, vals: list[float]) -> str:
    return "NC" if mean is None else _fmt(vals)


def results_table(runs: list[Run], scripted: Scripted | None = None) -> str:
    """Success and makespan on both instance sets first, return (reward named) last; on MAIF
    the scripted baselines as rows."""
    lines = ["| task | method | seeds | steps | success | makespan | held-out success | "
             "held-out makespan | greedy return (reward) |",
             "|---|---|---|---|---|---|---|---|---|"]
    by_task = _by(runs, "task")
    for task in _ordered(by_task, task_order()):
        by_method = _by(by_task[task], "method")
        for method in _ordered(by_method, method_order()):
            group = by_method[method]
            prefix = "eval" if all(r.final_eval_step() is not None for r in group) else "charts"
            cells = []
            for infix, _ in SETS:
                succ = [v for r in group
                        if (v := r.final(f"{prefix}/{infix}success_rate")) is not None]
                cells += [_fmt(succ, 2), _ms(*final_makespan(group, infix))]
            rets = [v for r in group if (v := r.final(f"{prefix}/episodic_return")) is not None]
            steps = max((int(s[0][-1]) for r in group for s in r.series.values() if len(s[0])),
                        default=0)
            lines.append(f"| {task} | {METHOD_LABEL.get(method, method).replace('$', '')} | "
                         f"{len(group)} | {steps} | {' | '.join(cells)} | "
                         f"{_fmt(rets)} ({group[0].reward}) |")
        for policy, label in SCRIPTED_LABELS.items():
            got = [(scripted or {}).get(task, {}).get((policy, which)) for _, which in SETS]
            if any(g is None for g in got):
                continue
            cells = [f"{g.success_rate:.2f} | {'NC' if g.makespan is None else f'{g.makespan:.1f}'}"
                     for g in got if g is not None]
            ret = got[0].episode_return if got[0] is not None else float("nan")
            lines.append(f"| {task} | {label} | - | - | {' | '.join(cells)} | "
                         f"{ret:.1f} ({got[0].reward if got[0] else '-'}) |")
    return "\n".join(lines)


def make_figures(logdir: Path, outdir: Path, scripted_instances: int | None = None) -> list[Path]:
    """Every figure and the table; returns the files written. ``scripted_instances`` overrides
    how many evaluation instances the scripted baselines play (default: the runs')."""
    if scripted_instances is not None and scripted_instances < 1:
        raise FigureError(f"--scripted-instances {scripted_instances}: allowed: an integer >= 1")
    runs = load_runs(logdir)
    if outdir.exists() and not outdir.is_dir():
        raise FigureError(f"{outdir} exists and is not a directory: name a directory for the "
                          "figures")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FigureError(f"{outdir}: cannot create the output directory: {e.strerror or e}"
                          ) from None
    scripted = scripted_baselines(runs, scripted_instances, outdir / SCRIPTED_CACHE)
    written: list[Path] = []
    skipped: list[str] = []
    for name, p in (("success", fig_success(runs, outdir, scripted)),
                    ("returns", fig_returns(runs, outdir)),
                    ("makespan", fig_makespan(runs, outdir, scripted)),
                    ("skewness", fig_skewness(runs, outdir))):
        if p is None:
            skipped.append(name)
        else:
            written.append(p)
    for name, fns in (("ablations", fig_ablations), ("P_H heatmaps", fig_ph_heatmaps)):
        ps = fns(runs, outdir)
        written += ps
        if not ps:
            skipped.append(name)
    md = [f"# Results of the {Path(logdir).name} suite", "",  # no machine path in docs
          "Success rate and makespan (steps to complete the formation), then return: final greedy "
          "evaluation on the training and the held-out instances (training episodes where a run "
          "has none); mean ± std over seeds; makespan over seeds that completed; NC = no seed "
          "completed. The scripted rows (MAIF) play the same instances.", "",
          results_table(runs, scripted), ""]
    md += ["Figures: " + ", ".join(p.name for p in written), ""]
    if skipped:
        md += [f"Skipped (no data in the logs): {', '.join(skipped)}", ""]
    (outdir / "results.md").write_text("\n".join(md))
    written.append(outdir / "results.md")
    return written


def main(argv: list[str] | None = None) -> int:
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="make_figures", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logdir", type=Path)
    p.add_argument("outdir", type=Path)
    p.add_argument("--scripted-instances", type=int, default=None,
                   help="instances the scripted baselines play (default: the runs' eval.instances)")
    args = p.parse_args(argv)
    try:
        written = make_figures(args.logdir, args.outdir, args.scripted_instances)
    except FigureError as e:
        print(f"make_figures: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # an unwritable output directory, a full disk
        print(f"make_figures: {e.filename or args.outdir}: {e.strerror or e}", file=sys.stderr)
        return 2
    for path in written:
        print(path)
    return 0
