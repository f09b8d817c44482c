#!/usr/bin/env python3
"""A suite's protocol report (docs/evaluation-protocol.md): IQM/mean with intervals, probability
of improvement, sample-efficiency curves, the absolute metric, marl-eval JSON, the claims table.

    .venv/bin/python scripts/protocol_report.py runs/maif-10-protocol docs/results/maif-10-protocol
"""

import sys

from sdhn_experiments.protocol_report import main

if __name__ == "__main__":
    sys.exit(main())
