#!/usr/bin/env python3
"""Learning quality of a speed option at equal env-steps: greedy success, makespan and return on
maif-tiny after the same number of team env-steps, per seed, with and without the option.
One training process at a time (a shared 2-core machine).

Logic and every option: ``sdhn_experiments.bench.learning`` (``--help``).
"""

import sys

from sdhn_experiments.bench.learning import main

if __name__ == "__main__":
    sys.exit(main())
