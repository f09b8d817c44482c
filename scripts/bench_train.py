#!/usr/bin/env python3
"""End-to-end training throughput of the in-process trainer: team env-steps/s wall and per
CPU-second, peak RSS, and the split of wall time into env stepping, action selection, critic
(target values + critic forward/backward/step), actor update and periodic greedy evaluation,
per env x algorithm; ``--load K`` runs K busy processes beside it (a shared machine).

Logic and every option: ``sdhn_experiments.bench.train`` (``--help``).
"""

import sys

from sdhn_experiments.bench.train import main

if __name__ == "__main__":
    sys.exit(main())
