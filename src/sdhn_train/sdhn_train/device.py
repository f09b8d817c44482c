"""``train.device``: where the in-process trainer's networks and tensors live.

Everything that crosses the device boundary goes through these helpers: NumPy arrays from the
environments go in with :func:`to_device`, results come back with :func:`to_numpy` (always a
host copy). Checkpoints hold NumPy arrays (``sdhn_train.checkpoint``), so a checkpoint written
on a GPU loads on a CPU and back.
"""

from __future__ import annotations

import numpy as np
import torch

DEVICES = ("cpu", "cuda", "auto")
PPO_ONLY = "the PPO algorithms (sdhn, mappo, dicg)"


def cuda_available() -> bool:
    return bool(torch.cuda.is_available())


def resolve_device(name: str) -> torch.device:
    """``cpu`` | ``cuda`` | ``auto`` -> a torch device (auto: cuda if torch sees a GPU)."""
    if name not in DEVICES:
        raise ValueError(f"train.device = {name!r} is invalid; allowed: {', '.join(DEVICES)}")
    if name == "auto":
        name = "cuda" if cuda_available() else "cpu"
    return torch.device(name)


def to_device(a: np.ndarray, device: torch.device) -> torch.Tensor:
    """A tensor on ``device`` from a NumPy array (shares its memory on the CPU)."""
    t = torch.from_numpy(a)
    return t if device.type == "cpu" else t.to(device, non_blocking=False)


def to_numpy(t: torch.Tensor) -> np.ndarray:
    """A NumPy array the caller owns, from a tensor on any device."""
    return t.detach().cpu().numpy().copy()
