"""What every training run shares, in-process or on the ROS trainer node: seeding (the one place),
episode metrics, and the P_H snapshots ``sdhn_experiments`` plots (the metrics log itself:
:mod:`sdhn_train.metrics_file`).
"""

from __future__ import annotations

import ctypes
import random
from pathlib import Path

import numpy as np
import torch

from sdhn_sim.envs.api import EpisodeStats
from sdhn_train.learners.base import HypergraphSamples

PH_DIR = "hypergraph"  # <run>/hypergraph/ph_<step>.npz

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
