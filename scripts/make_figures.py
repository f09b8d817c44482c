#!/usr/bin/env python3
"""Figures and the results table from run logs; logic in sdhn_experiments.figures.

    scripts/make_figures.py runs/paper figures/paper
"""

import sys

from sdhn_experiments.figures import main

if __name__ == "__main__":
    sys.exit(main())
