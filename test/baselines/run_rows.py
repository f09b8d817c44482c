"""A run's metrics as the runner tests compare them: the raw rows of its metrics.csv."""

from __future__ import annotations

import csv
from pathlib import Path


def metric_rows(run_dir: Path) -> list[tuple[str, str, str]]:
    """(step, tag, value) rows of a run's metrics, as written (no parsing), without the
    wall-clock dependent steps per second."""
    with open(run_dir / "metrics.csv", newline="") as f:
        return [(r["step"], r["tag"], r["value"]) for r in csv.DictReader(f)
                if r["tag"] != "charts/steps_per_second"]
