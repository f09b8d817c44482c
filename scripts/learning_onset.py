#!/usr/bin/env python3
"""When did each run start to learn? A markdown table of the training step at which a run's
greedy evaluation first rose above zero and first reached a level, with its policy entropy at
the start and its highest, from the runs' own metrics.csv (no re-evaluation).

Logic and every option: ``sdhn_experiments.learning_onset`` (``--help``).
"""

import sys

from sdhn_experiments.learning_onset import main

if __name__ == "__main__":
    sys.exit(main())
