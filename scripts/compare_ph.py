#!/usr/bin/env python3
"""P_H of SDHN runs side by side, at one equal step: the shape the skewness loss gives.

Logic and every option: ``sdhn_experiments.ph_compare`` (``--help``).
"""

import sys

from sdhn_experiments.ph_compare import main

if __name__ == "__main__":
    sys.exit(main())
