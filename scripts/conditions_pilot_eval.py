#!/usr/bin/env python3
"""Judge the training-under-conditions pilot (configs/suites/maif-20-conditions-pilot.yaml);
logic in sdhn_experiments.conditions_pilot_cli.

    nice -n 10 .venv/bin/python scripts/conditions_pilot_eval.py runs/dr-pilot \\
        --mark 40960 --instances 50 --out docs/results/conditions/training-pilot.json
"""

from __future__ import annotations

import sys

from sdhn_experiments.conditions_pilot_cli import main

if __name__ == "__main__":
    sys.exit(main())
