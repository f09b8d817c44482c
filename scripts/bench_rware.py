#!/usr/bin/env python3
"""RWARE env-steps per second: the real ``rware`` package vs the NumPy batched env, side by side.

Logic and every option: ``sdhn_experiments.bench.rware`` (``--help``).
"""

import sys

from sdhn_experiments.bench.rware import main

if __name__ == "__main__":
    sys.exit(main())
