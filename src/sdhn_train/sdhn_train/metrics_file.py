"""A run's ``metrics.csv``: the one writer and the one reader of the format.

Long format, one row per scalar: ``step, wall_time, tag, value`` (header first). The trainer
appends with :class:`MetricsLog`; everything that reads the file (the suite runner's resume,
the figures, the protocol reports, ``scripts/plot_curves.py``) goes through :func:`read_rows` or
:func:`read_series`, so the rules for a damaged file live here once:

- a row that does not parse (wrong column count, a non-integer step, a non-numeric value) is
  left out; the last row is the one a crash cuts off, any other is damage, which ``strict``
  readers refuse with :class:`MetricsFileError` naming the file and line;
- a step logged twice (a run resumed from a checkpoint before some rows it had logged) keeps
  its last value in :func:`read_series`;
- a carried copy is packed (``metrics.csv.xz``, :mod:`sdhn_train.run_files`):
  :func:`metrics_path` finds whichever the run holds and the readers open either.

Torch-free: TensorBoard is imported only when a :class:`MetricsLog` asks for it.
"""

from __future__ import annotations

import csv
import io
import lzma
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from sdhn_policy.weights import atomic_write_bytes
from sdhn_train.run_files import read_run_text, run_file

FILE = "metrics.csv"
HEADER = ("step", "wall_time", "tag", "value")

Series = tuple[np.ndarray, np.ndarray]
"""(steps, values) of one tag, steps ascending."""


class MetricsFileError(ValueError):
    """A file that is not a trainer's metrics.csv, or a damaged row inside one (one line)."""


def metrics_path(run_dir: Path) -> Path:
    """The run's metrics file: ``metrics.csv``, else a carried ``metrics.csv.xz``, else the
    plain name (which does not exist yet)."""
    return run_file(run_dir / FILE)


def _read_text(path: Path) -> str:
    try:
        return read_run_text(path)
    except lzma.LZMAError as e:
        raise MetricsFileError(f"{path}: not an xz-compressed metrics log ({e})") from None
    except (UnicodeDecodeError, EOFError) as e:
        raise MetricsFileError(f"{path}: not a text file ({type(e).__name__}; a trainer "
                               f"metrics.csv expected)") from None


def read_rows(path: Path, strict: bool = False) -> list[list[str]]:
    """The header and the rows that parse. ``strict``: a damaged row other than the last is a
    MetricsFileError; otherwise it is left out. An empty file has no rows ([])."""
    try:
        lines = list(csv.reader(io.StringIO(_read_text(path), newline="")))
    except csv.Error as e:
        raise MetricsFileError(f"{path}: not a CSV file ({e})") from None
    if not lines:
        return []  # a run that has just started has logged nothing yet
    header = lines[0]
    if not {"step", "tag", "value"} <= set(header):
        raise MetricsFileError(f"{path}: not a trainer metrics.csv (columns {header[:5]})")
    i_step, i_value = header.index("step"), header.index("value")
    kept = [header]
    for n, row in enumerate(lines[1:], start=2):
        try:
            if len(row) != len(header):
                raise ValueError(f"{len(row)} columns, expected {len(header)}")
            int(row[i_step])
            float(row[i_value])
        except ValueError as e:
            if strict and n != len(lines):  # the last row is the one a crash cuts off
                raise MetricsFileError(
                    f"{path}: line {n} is not a metrics row ({e}); allowed: "
                    f"{', '.join(header)} with an integer step and a numeric value") from None
            continue
        kept.append(row)
    return kept


def read_series(path: Path) -> dict[str, Series]:
    """{tag: (steps, values)} (strict reading); a step logged twice keeps its last value."""
    rows = read_rows(path, strict=True)
    if not rows:
        return {}
    header = rows[0]
    i_step, i_tag, i_value = header.index("step"), header.index("tag"), header.index("value")
    by_tag: dict[str, dict[int, float]] = defaultdict(dict)
    for row in rows[1:]:
        by_tag[row[i_tag]][int(row[i_step])] = float(row[i_value])
    out = {}
    for tag, by_step in by_tag.items():
        steps = np.array(sorted(by_step))
        out[tag] = (steps, np.array([by_step[k] for k in steps]))
    return out


def trim(path: Path, step: int) -> int:
    """Drop rows of the metrics file ``path`` logged after ``step`` (the checkpoint a resume
    starts from) and rows that do not parse (cut off by a crash: the resumed run appends after
    them, and a reader would take them for data). Atomic; returns the rows dropped. A missing
    file, or one that is not a metrics file, is left as it is (0)."""
    if not path.is_file():
        return 0
    try:
        text = _read_text(path)
        rows = read_rows(path)
    except MetricsFileError:
        return 0
    if not rows:
        return 0
    total = len(list(csv.reader(io.StringIO(text, newline="")))) - 1
    i_step = rows[0].index("step")
    keep = [rows[0], *(r for r in rows[1:] if int(r[i_step]) <= step)]
    dropped = total - (len(keep) - 1)
    if dropped:
        buf = io.StringIO()
        csv.writer(buf).writerows(keep)
        atomic_write_bytes(path, buf.getvalue().encode())
    return dropped


class MetricsLog:
    """The writer: appends rows to ``<run>/metrics.csv`` (+ optional TensorBoard scalars)."""

    def __init__(self, run_dir: Path, tensorboard: bool) -> None:
        self._f: TextIO = open(run_dir / FILE, "a", newline="")  # noqa: SIM115
        self._csv = csv.writer(self._f)
        if self._f.tell() == 0:
            self._csv.writerow(HEADER)
        self._tb: Any = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(run_dir))

    def write(self, step: int, metrics: dict[str, float]) -> None:
        now = time.time()
        for tag, value in metrics.items():
            self._csv.writerow([step, f"{now:.3f}", tag, f"{value:.6g}"])
            if self._tb is not None:
                self._tb.add_scalar(tag, value, step)
        self._f.flush()

    def close(self) -> None:
        self._f.close()
        if self._tb is not None:
            self._tb.close()
