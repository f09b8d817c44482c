#!/usr/bin/env python3
"""RWARE baselines: deliveries and return per episode of random and scripted policies.

Logic and every option: ``sdhn_experiments.rware_baseline_eval`` (``--help``).
"""

import sys

from sdhn_experiments.rware_baseline_eval import main

if __name__ == "__main__":
    sys.exit(main())
