#!/usr/bin/env python3
"""Scripted MAIF baselines on the training and the held-out instance sets.

Logic and every option: ``sdhn_experiments.scripted_eval`` (``--help``).
"""

import sys

from sdhn_experiments.scripted_eval import main

if __name__ == "__main__":
    sys.exit(main())
