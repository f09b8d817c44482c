"""What every training run shares, in-process or on the ROS trainer node: seeding (the one place),
the metrics log, episode metrics, and the P_H snapshots ``sdhn_train.analysis`` plots.
"""

from __future__ import annotations

import csv
import ctypes
import io
import lzma
import random
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch

from sdhn_policy.weights import atomic_write_bytes
from sdhn_sim.envs.api import EpisodeStats
from sdhn_train.learners.base import HypergraphSamples

PH_DIR = "hypergraph"  # <run>/hypergraph/ph_<step>.npz
METRICS_FILE = "metrics.csv"
PACKED_SUFFIX = ".xz"
"""A run carried in the repository keeps its text logs xz-compressed (``metrics.csv.xz``,
sdhn_train.analysis.carry); the readers below take either form, so a report reads a carried
suite as it reads a log directory."""


def packed(path: Path) -> Path:
    """The compressed twin of a run file (``metrics.csv`` -> ``metrics.csv.xz``)."""
    return path.with_name(path.name + PACKED_SUFFIX)


def run_file(path: Path) -> Path:
    """``path`` if it exists, else its compressed twin if that does (else ``path``, for the
    caller's own "missing" message)."""
    return packed(path) if not path.exists() and packed(path).exists() else path


def metrics_file(run_dir: Path) -> Path:
    """A run's metrics log as it is on disk: ``metrics.csv``, or ``metrics.csv.xz`` carried."""
    return run_file(run_dir / METRICS_FILE)


def open_run_text(path: Path) -> TextIO:
    """A run's text file for reading (UTF-8, CSV newlines), decompressed if it is packed; with
    ``run_file``'s fallback, so ``open_run_text(run / "metrics.csv")`` reads a carried copy."""
    path = run_file(path)
    if path.name.endswith(PACKED_SUFFIX):
        return lzma.open(path, "rt", encoding="utf-8", newline="")
    return open(path, encoding="utf-8", newline="")


def read_run_text(path: Path) -> str:
    with open_run_text(path) as f:
        return f.read()


def seed_everything(seed: int, deterministic: bool, threads: int) -> np.random.Generator:
    """The one place that seeds: Python, NumPy (returned generator), torch."""
    random.seed(seed)
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(deterministic)
    return np.random.default_rng(seed)


# mallopt(3) parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_MIB = 1 << 20


def retain_freed_memory() -> bool:
    """Make glibc's malloc keep freed memory for reuse: blocks up to 32 MiB (its maximum) come
    from the heap instead of their own mmap, and the heap is trimmed only past 1 GiB free.

    Why: an update allocates and frees hundreds of large temporaries (a [T, b, N, 64] float
    tensor is 2.6 MiB). Under glibc's defaults each is a fresh mmap, so every page of it faults
    on first touch and is zeroed by the kernel, and munmap on free: 80-130 k minor faults per
    SDHN maif-10 update. Reused heap memory faults once. The numbers computed are the same
    (this only changes where tensors live); peak RSS stays the peak of live tensors (measured:
    587-627 against 590-613 MiB). Returns False where there is no glibc (nothing changed)."""
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # every parameter is set even if one is refused (a list, not a short-circuiting generator)
    accepted = [mallopt(param, value) == 1 for param, value in (
        (_M_MMAP_THRESHOLD, 32 * _MIB), (_M_TRIM_THRESHOLD, 1024 * _MIB),
        (_M_TOP_PAD, 64 * _MIB))]
    return all(accepted)


def episode_metrics(prefix: str, episodes: list[EpisodeStats]) -> dict[str, float]:
    if not episodes:
        return {}
    out = {
        f"{prefix}/episodic_return": float(np.mean([e.episode_return for e in episodes])),
        f"{prefix}/episode_length": float(np.mean([e.length for e in episodes])),
        f"{prefix}/success_rate": float(np.mean([e.completed for e in episodes])),
        f"{prefix}/collisions": float(np.mean([e.collisions for e in episodes])),
    }
    done = [e.makespan for e in episodes if e.makespan is not None]
    if done:  # makespan of completed episodes only (NC episodes have none)
        out[f"{prefix}/makespan"] = float(np.mean(done))
    return out


def trim_metrics(run_dir: Path, step: int) -> int:
    """Drop rows of ``<run>/metrics.csv`` logged after ``step`` (the checkpoint a resume starts
    from), so the resumed run's rows do not duplicate them. Atomic; returns the rows dropped."""
    path = run_dir / "metrics.csv"
    if not path.is_file():
        return 0
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return 0
    # A row cut off by a crash (fewer columns, a half-written value) goes too: the resumed
    # run appends after it, and a reader would take it for data.
    keep = [rows[0]] + [r for r in rows[1:] if len(r) == len(rows[0]) and r[0].isdigit()
                        and _is_number(r[-1]) and int(r[0]) <= step]
    dropped = len(rows) - len(keep)
    if dropped:
        buf = io.StringIO()
        csv.writer(buf).writerows(keep)
        atomic_write_bytes(path, buf.getvalue().encode())
    return dropped


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class MetricsLog:
    """CSV (long format: step, wall_time, tag, value) + optional TensorBoard."""

    def __init__(self, run_dir: Path, tensorboard: bool) -> None:
        self._f: TextIO = open(run_dir / "metrics.csv", "a", newline="")  # noqa: SIM115
        self._csv = csv.writer(self._f)
        if self._f.tell() == 0:
            self._csv.writerow(["step", "wall_time", "tag", "value"])
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


def save_ph_snapshot(run_dir: Path, step: int, samples: HypergraphSamples | None) -> Path | None:
    """Write ``<run>/hypergraph/ph_<step>.npz``: P_H [N, M] of environment 0 at the rollout's last
    step (``ph_last``) and averaged over the rollout's steps and environments (``ph_mean``).
    None (nothing written) for critics without hypergraphs."""
    if samples is None:
        return None
    p = samples.p_h  # [T, B, N, M]
    out = run_dir / PH_DIR / f"ph_{step:012d}.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, step=np.int64(step), ph_last=p[-1, 0], ph_mean=p.mean((0, 1)))
    return out
