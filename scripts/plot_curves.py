#!/usr/bin/env python3
"""Learning curves (PNG) from run CSVs written by the trainer (``<run>/metrics.csv``).

Logic and every option: ``sdhn_experiments.curves`` (``--help``).
"""

import sys

from sdhn_experiments.curves import main

if __name__ == "__main__":
    sys.exit(main())
