#!/usr/bin/env python3
"""Run an experiment suite (methods x tasks x seeds x budget); logic in
sdhn_experiments.experiments (and .ray_backend for --backend ray).

    scripts/run_experiments.py configs/suites/paper.yaml --budget quick --logdir runs/paper-quick
    scripts/run_experiments.py configs/suites/paper.yaml --budget paper --jobs 2
Rerunning the same command resumes: finished runs are skipped, interrupted ones resume.
"""

import sys

from sdhn_experiments.experiments_cli import main

if __name__ == "__main__":
    sys.exit(main())
