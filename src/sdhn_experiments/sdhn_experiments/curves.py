"""Learning curves (PNG) from run CSVs written by the trainer (``<run>/metrics.csv``).

    python scripts/plot_curves.py runs/maif-10__sdhn__* runs/maif-10__mappo__* \
        --tags charts/episodic_return eval/success_rate --out curves.png

Runs are grouped by "<env>__<algo>" (the run-name prefix); each group is drawn as the mean over
its seeds with a min-max band, on a common step grid (up to the shortest seed's last step);
``--per-run`` draws every run on its own instead (seeds of unequal length).
``--hline "scripted=29.9"`` (repeatable) draws a baseline's value as a dashed horizontal line on
every panel; ``--titles`` replaces the panel titles (default: the tags), ``--suptitle`` adds one
line above them (budget, seeds); ``--symlog`` makes the y axis linear up to 1 and logarithmic
above (a learner near 0 beside a baseline at 30).

    python scripts/plot_curves.py runs/rware-3__* --tags eval/episodic_return \
        --hline "random=0.1" --hline "scripted (centralised)=29.9" --out rware-3_curves.png
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import EngFormatter

from sdhn_train.metrics_file import metrics_path, read_series


def group_name(run_dir: Path) -> str:
    parts = run_dir.name.split("__")
    return "__".join(parts[:2]) if len(parts) >= 2 else run_dir.name


def parse_hline(text: str) -> tuple[str, float]:
    """``"label=value"`` -> (label, value); the label may itself hold '='."""
    label, sep, value = text.rpartition("=")
    if not sep or not label:
        raise argparse.ArgumentTypeError(f"--hline wants LABEL=VALUE, got {text!r}")
    try:
        return label, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--hline value is not a number: {text!r}") from None


def plot(runs: list[Path], tags: list[str], out: Path, smooth: int = 1, *,
         hlines: list[tuple[str, float]] | None = None, titles: list[str] | None = None,
         suptitle: str | None = None, per_run: bool = False,
         symlog: bool = False) -> dict[str, list[str]]:
    """Draws ``out``; returns, per tag, the labels of what its panel shows (curves, baselines)."""
    groups: dict[str, list[dict[str, tuple[np.ndarray, np.ndarray]]]] = defaultdict(list)
    for run in runs:
        csv_path = metrics_path(run) if run.is_dir() else run
        name = csv_path.parent.name if per_run else group_name(csv_path.parent)
        groups[name].append(read_series(csv_path))
    drawn: dict[str, list[str]] = {}
    fig, axes = plt.subplots(1, len(tags), figsize=(5 * len(tags), 3.6), squeeze=False)
    for ax, tag, title in zip(axes[0], tags, titles or tags, strict=True):
        for name, members in sorted(groups.items()):
            curves = [m[tag] for m in members if tag in m and len(m[tag][0])]
            if not curves:
                continue
            grid = np.linspace(0, min(c[0][-1] for c in curves), 200)
            ys = []
            for steps, raw in curves:
                vals = raw
                if smooth > 1 and len(raw) >= smooth:
                    vals = np.convolve(raw, np.ones(smooth) / smooth, mode="same")
                ys.append(np.interp(grid, steps, vals))
            y = np.stack(ys)
            ax.plot(grid, y.mean(0), label=f"{name} (n={len(ys)})")
            if len(ys) > 1:
                ax.fill_between(grid, y.min(0), y.max(0), alpha=0.2)
        for k, (label, value) in enumerate(hlines or []):
            ax.axhline(value, linestyle="--", linewidth=1, color=f"C{len(groups) + k}",
                       label=f"{label}: {value:g}")
        ax.set_title(title, fontsize=9)
        drawn[tag] = ax.get_legend_handles_labels()[1]
        ax.set_xlabel("team env-steps")
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 200k, 1M: no overlapping digits
        if symlog:
            ax.set_yscale("symlog", linthresh=1.0)
            values = [v for line in ax.get_lines() for v in np.asarray(line.get_ydata(), float)]
            if values and min(values) >= 0:  # no empty negative decade under the curves
                ax.set_ylim(-0.05, 1.5 * max(*values, 1.0))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if suptitle:
        fig.suptitle(suptitle, fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return drawn


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="run directories or metrics.csv files")
    p.add_argument("--tags", nargs="+",
                   default=["charts/episodic_return", "eval/success_rate", "eval/makespan"])
    p.add_argument("--smooth", type=int, default=1, help="moving-average window (points)")
    p.add_argument("--hline", action="append", type=parse_hline, default=[],
                   metavar="LABEL=VALUE", help="a baseline drawn on every panel (repeatable)")
    p.add_argument("--symlog", action="store_true", help="y linear to 1, logarithmic above")
    p.add_argument("--per-run", action="store_true", help="one line per run, no seed groups")
    p.add_argument("--titles", nargs="+", help="panel titles, one per tag (default: the tags)")
    p.add_argument("--suptitle", help="one line above the panels")
    p.add_argument("--out", type=Path, default=Path("curves.png"))
    args = p.parse_args(argv)
    if args.titles and len(args.titles) != len(args.tags):
        p.error(f"--titles wants {len(args.tags)} titles, one per tag, got {len(args.titles)}")
    missing = [r for r in args.runs if not (metrics_path(r) if r.is_dir() else r).exists()]
    if missing:
        print(f"plot_curves: no metrics.csv in {', '.join(map(str, missing))}", file=sys.stderr)
        return 2
    plot(args.runs, args.tags, args.out, args.smooth, hlines=args.hline, titles=args.titles,
         suptitle=args.suptitle, per_run=args.per_run, symlog=args.symlog)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
