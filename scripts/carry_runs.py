#!/usr/bin/env python3
"""Carry a suite's log directory across machines inside the repository (long suites outlive a
machine); logic in sdhn_experiments.carry.

    scripts/carry_runs.py save <runs>/rware carry/rware-long        # before the machine goes
    scripts/carry_runs.py restore carry/rware-long <runs>/rware     # on the next one, then
    scripts/run_experiments.py configs/suites/rware.yaml --budget long --logdir <runs>/rware
"""

import sys

from sdhn_experiments.carry import main

if __name__ == "__main__":
    sys.exit(main())
