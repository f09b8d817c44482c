#!/usr/bin/env python3
"""Benchmark of the ROS deployment stack (prints figures; not a test); ``--fleet`` runs
the fleet cost curve (scripts/bench_fleet.py).

Logic and every option: ``sdhn_experiments.bench.ros`` (``--help``).
"""

import sys

from sdhn_experiments.bench.ros import main

if __name__ == "__main__":
    sys.exit(main())
