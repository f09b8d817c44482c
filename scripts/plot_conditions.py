#!/usr/bin/env python3
"""The degradation figure and table of ``scripts/eval_conditions.py`` results.

Logic and every option: ``sdhn_experiments.condition_figures`` (``--help``).
"""

import sys

from sdhn_experiments.condition_figures import main

if __name__ == "__main__":
    sys.exit(main())
