#!/usr/bin/env python3
"""How a MAIF actor behaves on its goal and one cell from it (stays, steps onto it), per side.

Logic and every option: ``sdhn_experiments.arrival_probe`` (``--help``).
"""

import sys

from sdhn_experiments.arrival_probe import main

if __name__ == "__main__":
    sys.exit(main())
