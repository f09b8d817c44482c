#!/usr/bin/env python3
"""Shipped MAIF policies under deployment conditions: success (survivors' success under robot
failure), makespan and makespan over the ideal world, with 95 % intervals, at several severities
of each condition (sdhn_sim.envs.conditions; logic in sdhn_experiments.condition_eval).

Logic and every option: ``sdhn_experiments.condition_eval_cli`` (``--help``).
"""

import sys

from sdhn_experiments.condition_eval_cli import main

if __name__ == "__main__":
    sys.exit(main())
