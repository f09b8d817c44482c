#!/usr/bin/env python3
"""Long step-for-step comparison of the batched RWARE with the real ``rware`` package.

Logic and every option: ``sdhn_experiments.bench.rware_equality`` (``--help``).
"""

import sys

from sdhn_experiments.bench.rware_equality import main

if __name__ == "__main__":
    sys.exit(main())
