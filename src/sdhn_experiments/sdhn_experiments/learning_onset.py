"""When did each run start to learn? A markdown table of the training step at which a run's
greedy evaluation first rose above zero and first reached a level, with its policy entropy at
the start and its highest, from the runs' own metrics.csv (no re-evaluation).

    .venv/bin/python scripts/learning_onset.py <runs>/rware <runs>/rware-warm-temperature \\
        --match rware-3__ --match _warm --level 10

The warm-start screen (configs/suites/rware-warm-temperature.yaml) compares its runs with the
rware suite's by this table: on a sparse reward, a run whose first deliveries come late or never
is an exploration failure, whatever its final score would have been.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sdhn_experiments.figures import FigureError, Run, read_run

ENTROPY = "losses/entropy"


def first_step(run: Run, tag: str, above: float) -> int | None:
    """The first logged step at which ``tag`` exceeds ``above`` (None: never so far)."""
    series = run.series.get(tag)
    if series is None:
        return None
    hits = np.nonzero(series[1] > above)[0]
    return int(series[0][hits[0]]) if len(hits) else None


def onset_row(run: Run, tag: str, level: float, at_step: int) -> list[str]:
    steps = run.series[tag][0] if tag in run.series else np.array([0])
    last = int(steps[-1]) if len(steps) else 0

    def at(step: int | None) -> str:
        return f"{step / 1e6:.2f} M" if step is not None else f"not by {last / 1e6:.2f} M"

    entropy = run.series.get(ENTROPY, (None, np.array([])))[1]
    start, top = ((f"{entropy[0]:.2f}", f"{entropy.max():.2f}") if len(entropy)
                  else ("—", "—"))
    final = run.final(tag)
    then = run.value_at(tag, at_step) if last >= at_step else None  # not reached yet: no value
    return [run.path.name, at(first_step(run, tag, 0.0)), at(first_step(run, tag, level - 1e-9)),
            f"{then:.1f}" if then is not None else "—",
            f"{final:.1f}" if final is not None else "—", start, top]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logdirs", nargs="+", type=Path, help="log directories of run directories")
    p.add_argument("--match", action="append", default=[],
                   help="keep runs whose directory name contains this (all of them, if repeated)")
    p.add_argument("--tag", default="eval/deliveries", help="the greedy evaluation's metric")
    p.add_argument("--level", type=float, default=10.0, help="the second threshold")
    p.add_argument("--at", type=float, default=3e6, help="also the value at this step (a "
                                                         "screen's budget, to compare longer runs)")
    args = p.parse_args(argv)
    rows = []
    for logdir in args.logdirs:
        if not logdir.is_dir():
            p.error(f"{logdir}: not a directory")
        for d in sorted(logdir.iterdir()):
            if not d.is_dir() or not all(m in d.name for m in args.match):
                continue
            if not (d / "metrics.csv").is_file():
                continue  # created by the runner, nothing logged yet
            try:
                rows.append(onset_row(read_run(d), args.tag, args.level, int(args.at)))
            except FigureError as e:
                print(f"learning_onset: {e}", file=sys.stderr)
                return 2
    if not rows:
        print("learning_onset: no run matches", file=sys.stderr)
        return 1
    print(f"| run | first {args.tag} > 0 | first ≥ {args.level:g} | at {args.at / 1e6:g} M | "
          f"latest | entropy at start | highest entropy |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
