#!/usr/bin/env python3
"""The robustness suite (logic in sdhn_experiments.robustness): every protocol actor (restored
from git history through docs/results/robustness/actors.json) and the shipped models under every
deployment condition at four severities; resumable; then the report.

    nice -n 10 .venv/bin/python scripts/robustness_suite.py run --tasks maif-10 \
        --instances 100 --out /tmp/robustness
    .venv/bin/python scripts/robustness_suite.py run --models models/maif-10-sdhn \
        --out /tmp/robustness
    .venv/bin/python scripts/robustness_suite.py report /tmp/robustness docs/results/robustness
"""

import sys

from sdhn_experiments.robustness import main

if __name__ == "__main__":
    sys.exit(main())
