"""Shared fixtures of the algorithm tests: few threads (2 shared cores), import paths."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
for pkg in ("sdhn_sim", "sdhn_policy", "sdhn_train"):
    path = str(ROOT / "src" / pkg)
    if path not in sys.path:
        sys.path.insert(0, path)

import torch  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(0)
