#!/usr/bin/env python3
"""Evaluate MAIF actors on whole instance sets: success with a 95 % interval, makespan against
the planner's, success per map, deadlocks. JSON + a markdown table.

Logic and every option: ``sdhn_experiments.evaluate_policy`` (``--help``).
"""

import sys

from sdhn_experiments.evaluate_policy import main

if __name__ == "__main__":
    sys.exit(main())
