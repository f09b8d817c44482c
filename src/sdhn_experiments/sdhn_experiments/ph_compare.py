"""P_H of SDHN runs side by side, at one equal step: the shape the skewness loss gives.

    .venv/bin/python scripts/compare_ph.py RUN_A RUN_B [--step 303104] --out docs/results/x.png

For each run: the mean P_H (robots x hyperedges) of its snapshot at ``--step`` (default: the
last step every run has), titled with its lambda_Sk, greedy success and makespan on the training
and held-out sets at that step (NC when none completed), the skewness of its sampled H and the
mean hyperedge size. Reads only what the trainer wrote (``hypergraph/ph_*.npz``, metrics.csv).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_experiments.figures import Run, lambda_sk, read_run
from sdhn_train.runs import PH_DIR


def snapshot(run: Run, step: int) -> np.ndarray:
    with np.load(run.path / PH_DIR / f"ph_{step:012d}.npz") as z:
        return np.array(z["ph_mean"])


def steps_of(run: Run) -> set[int]:
    return {int(p.stem.split("_")[1]) for p in (run.path / PH_DIR).glob("ph_*.npz")}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", type=Path, nargs="+")
    p.add_argument("--step", type=int, help="snapshot step (default: last one all runs have)")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    runs = [read_run(r) for r in args.runs]
    common = set.intersection(*(steps_of(r) for r in runs))
    step = args.step if args.step is not None else max(common, default=-1)
    if step not in common:
        print(f"compare_ph: no P_H snapshot at step {step} in every run", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(4.6 * len(runs), 3.9), squeeze=False)
    im: Any = None
    for ax, run in zip(axes[0], runs, strict=True):
        ph = snapshot(run, step)
        im = ax.imshow(ph, vmin=0.0, vmax=1.0, cmap="viridis", aspect="auto")

        def fmt(tag: str, digits: int = 2, run: Run = run) -> str:
            v = run.value_at(tag, step)
            return "NC" if v is None else f"{v:.{digits}f}"

        line = (f"$\\lambda_{{Sk}}$ = {lambda_sk(run):g}, step {step}\n"
                f"success {fmt('eval/success_rate')} | {fmt('eval/heldout_success_rate')}, "
                f"makespan {fmt('eval/makespan', 1)} | {fmt('eval/heldout_makespan', 1)}\n"
                f"Sk {fmt('hypergraph/skewness')}, mean edge size "
                f"{fmt('hypergraph/mean_edge_size')}, mean p {ph.mean():.2f}")
        ax.set_title(line, fontsize=8)
        ax.set_xticks(range(ph.shape[1]))
        ax.set_yticks(range(ph.shape[0]))
        ax.set_xlabel("hyperedge j")
        ax.set_ylabel("robot i")
        print(f"{run.path.name}: {line.replace(chr(10), '; ')}")
    fig.colorbar(im, ax=list(axes[0]), label="mean $P_H$ over the rollout")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    plt.close(fig)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
