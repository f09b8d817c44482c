"""Benchmarks and long checks: they print figures (or a verdict) and never assert on time, which
tests must not do. Each module has a ``main`` that a thin wrapper under ``scripts/`` calls
(``scripts/bench_ros.py`` runs ``sdhn_experiments.bench.ros``), and runs as ``python -m`` too.

The deployment benchmarks start the launcher on the checkout's launch configs and shipped models,
so they run from a source checkout (``scripts/setup.sh`` installs the packages editable into it):
``CHECKOUT`` is that folder.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def _checkout() -> Path:
    """The source checkout this package is installed from (configs/launch and scripts/ beside
    src/), else the working directory (a non-editable install run from a checkout). Found from
    the installed package (importlib.resources), not this module's own path, which moves when
    the module does."""
    package = Path(str(resources.files("sdhn_experiments")))
    for folder in package.resolve().parents:
        if (folder / "configs" / "launch").is_dir() and (folder / "scripts").is_dir():
            return folder
    return Path.cwd()


CHECKOUT = _checkout()
"""The checkout holding configs/, models/ and scripts/ (commands run with it as their cwd)."""
