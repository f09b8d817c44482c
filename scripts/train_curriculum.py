#!/usr/bin/env python3
"""Train MAIF through a team-size curriculum, each stage warm-started from the previous actor.

Logic and every option: ``sdhn_experiments.curriculum`` (``--help``).
"""

import sys

from sdhn_experiments.curriculum import main

if __name__ == "__main__":
    sys.exit(main())
