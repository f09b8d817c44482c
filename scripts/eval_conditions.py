#!/usr/bin/env python3
"""Shipped policies under deployment conditions: MAIF success (survivors' success under robot
failure), makespan and makespan over the ideal world; RWARE deliveries per episode and the
latency mechanism's counts (models or scripted:TASK); with 95 % intervals, at several severities
of each condition (sdhn_sim.envs.conditions; logic in sdhn_experiments.condition_eval and
sdhn_experiments.rware_conditions).

Logic and every option: ``sdhn_experiments.condition_eval_cli`` (``--help``).
"""

import sys

from sdhn_experiments.condition_eval_cli import main

if __name__ == "__main__":
    sys.exit(main())
