#!/usr/bin/env python3
"""Decision latency of the actor processes, read from their own /diagnostics (prints figures;
not a test).

Logic and every option: ``sdhn_experiments.bench.decision_latency`` (``--help``).
"""

import sys

from sdhn_experiments.bench.decision_latency import main

if __name__ == "__main__":
    sys.exit(main())
