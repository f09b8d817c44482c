#!/usr/bin/env python3
"""Throughput of the environments (prints figures; not a test).

Logic and every option: ``sdhn_experiments.bench.envs`` (``--help``).
"""

import sys

from sdhn_experiments.bench.envs import main

if __name__ == "__main__":
    sys.exit(main())
