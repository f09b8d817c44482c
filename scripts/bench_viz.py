#!/usr/bin/env python3
"""Cost of the Foxglove viz: encoding per message, and per-state overhead with and without a client.

Logic and every option: ``sdhn_experiments.bench.viz`` (``--help``).
"""

import sys

from sdhn_experiments.bench.viz import main

if __name__ == "__main__":
    sys.exit(main())
