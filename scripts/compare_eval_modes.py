#!/usr/bin/env python3
"""Compare deployment modes of one policy (greedy, sampled at temperatures, unstick) from
``evaluate_policy.py --out`` files: success with its interval, deadlocks, and the makespan over
the planner's on only the instances every mode completed (a fair makespan comparison: a mode
that solves harder instances is not charged for them).

Logic and every option: ``sdhn_experiments.eval_modes`` (``--help``).
"""

import sys

from sdhn_experiments.eval_modes import main

if __name__ == "__main__":
    sys.exit(main())
