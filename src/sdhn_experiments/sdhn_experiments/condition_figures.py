"""The degradation figure and table of ``scripts/eval_conditions.py`` results.

    .venv/bin/python scripts/plot_conditions.py /tmp/cond/*.json \\
        --figure docs/results/conditions/degradation.png --markdown docs/results/conditions/table.md

One panel pair per condition (success with its 95 % interval over maps; makespan over the ideal
world with its 95 % interval over instances) against severity, one line per policy and mode
(dead reckoning dashed). Inputs: ``eval_conditions.py --out`` lists, or results files
``{"note": ..., "runs": {name: list}}``; rows measured twice (same policy, task, mode,
condition, severity) keep the last one read.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sdhn_experiments.condition_eval_cli import SEVERITY_NAMES, markdown


def load_rows(paths: list[Path]) -> list[dict[str, Any]]:
    rows: dict[tuple[str, str, str, str, str], dict[str, Any]] = {}
    for p in paths:
        data = json.loads(p.read_text())
        if isinstance(data, dict):  # {"note": ..., "runs": {name: rows}}: a results file
            data = [r for run in data["runs"].values() for r in run]
        for r in data:
            r.pop("records", None)
            rows[(r["policy"], r["task"], r["mode"], r["condition"], r["severity"])] = r
    return list(rows.values())


def figure(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = [c for c in SEVERITY_NAMES if any(r["condition"] == c for r in rows)]
    fig, axes = plt.subplots(2, len(conds), figsize=(3.2 * len(conds), 5.6), squeeze=False)
    lines = sorted({(r["policy"], r["task"], r["mode"]) for r in rows if r["condition"] != "ideal"})
    for j, c in enumerate(conds):
        for idx, (pol, task, mode) in enumerate(lines):
            colour = plt.get_cmap("tab20")(idx % 20)  # one colour per line in every panel
            ideal = [r for r in rows if (r["policy"], r["task"], r["condition"]) ==
                     (pol, task, "ideal") and r["mode"].replace(", dead reckoning", "") ==
                     mode.replace(", dead reckoning", "")]
            pts = sorted((float(r["severity"]), r["summary"]) for r in rows
                         if (r["policy"], r["task"], r["mode"], r["condition"]) ==
                         (pol, task, mode, c))
            if not pts:
                continue
            if ideal:  # severity 0, or rate 1 for the slow robots
                pts = sorted([(1.0 if c == "slow_half" else 0.0, ideal[0]["summary"]), *pts],
                             key=lambda xp: xp[0])
            xs = [x for x, _ in pts]
            style = "--" if "dead reckoning" in mode else "-"
            label = f"{pol} on {task}: {mode}" if pol.split("-sdhn")[0] != task else \
                f"{pol}: {mode}"
            s = [p["success_rate"] for _, p in pts]
            lo = [p["success_rate"] - p["success_ci95_maps"][0] for _, p in pts]
            hi = [p["success_ci95_maps"][1] - p["success_rate"] for _, p in pts]
            axes[0, j].errorbar(xs, s, yerr=[lo, hi], linestyle=style, marker="o", ms=3,
                                capsize=2, label=label, color=colour)
            mk = [(x, p) for x, p in pts if p.get("makespan_over_ideal") is not None]
            if mk:
                m = [p["makespan_over_ideal"] for _, p in mk]
                mlo = [p["makespan_over_ideal"] - p["makespan_over_ideal_ci95"][0] for _, p in mk]
                mhi = [p["makespan_over_ideal_ci95"][1] - p["makespan_over_ideal"] for _, p in mk]
                axes[1, j].errorbar([x for x, _ in mk], m, yerr=[mlo, mhi], linestyle=style,
                                    marker="o", ms=3, capsize=2, color=colour)
        axes[0, j].set_title(c.replace("_", " "), fontsize=10)
        axes[0, j].set_ylim(-0.03, 1.03)
        axes[1, j].set_xlabel(SEVERITY_NAMES[c], fontsize=9)
        axes[1, j].axhline(1.15, color="grey", lw=0.6, ls=":")
        if c == "slow_half":
            axes[0, j].invert_xaxis()
            axes[1, j].invert_xaxis()
    axes[0, 0].set_ylabel("success (survivors' under failure)")
    axes[1, 0].set_ylabel("makespan / ideal (paired)")
    fig.suptitle("maif-10 under deployment conditions", fontsize=11)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for ax in axes[0, 1:]:
        h, lab = ax.get_legend_handles_labels()
        for hh, ll in zip(h, lab, strict=True):
            if ll not in labels:
                handles.append(hh)
                labels.append(ll)
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.03 + 0.025 * ((len(labels) + 1) // 2), 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("results", nargs="+", type=Path, help="eval_conditions.py JSON files")
    p.add_argument("--figure", type=Path)
    p.add_argument("--markdown", type=Path)
    p.add_argument("--summary", type=Path, help="the rows without per-instance records (JSON)")
    args = p.parse_args(argv)
    rows = load_rows(args.results)
    if not rows:
        print("plot_conditions: no rows in the inputs", file=sys.stderr)
        return 2
    order = {c: i for i, c in enumerate(["ideal", *SEVERITY_NAMES])}
    rows.sort(key=lambda r: (r["policy"], r["task"], order.get(r["condition"], 99),
                             r["mode"], float(r["severity"]) if r["severity"] != "-" else 0))
    if args.figure:
        figure(rows, args.figure)
    table = markdown(rows)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(table)
    if args.summary:
        args.summary.write_text(json.dumps(rows, indent=1) + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
