"""A run directory's text files as they are on disk: plain in a log directory, or packed.

A run carried in the repository keeps its text logs xz-compressed (``metrics.csv.xz``, see
``sdhn_experiments.carry``); the readers take either form through :func:`run_file` and
:func:`open_run_text`, so a report reads a carried suite as it reads a log directory.
Torch-free, so reports and plots read runs without the training stack.
"""

from __future__ import annotations

import lzma
from pathlib import Path
from typing import TextIO

PACKED_SUFFIX = ".xz"


def packed(path: Path) -> Path:
    """The compressed twin of a run file (``metrics.csv`` -> ``metrics.csv.xz``)."""
    return path.with_name(path.name + PACKED_SUFFIX)


def run_file(path: Path) -> Path:
    """``path`` if it exists, else its compressed twin if that does (else ``path``, for the
    caller's own "missing" message)."""
    return packed(path) if not path.exists() and packed(path).exists() else path


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
