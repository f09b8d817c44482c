#!/usr/bin/env python3
"""Runs/hour and scheduling overhead per run of run_experiments' backends, local and Ray, on
the same tiny suite (prints figures; not a test).

Logic and every option: ``sdhn_experiments.bench.experiment_backends`` (``--help``).
"""

import sys

from sdhn_experiments.bench.experiment_backends import main

if __name__ == "__main__":
    sys.exit(main())
