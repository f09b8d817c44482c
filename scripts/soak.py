#!/usr/bin/env python3
"""Soak: a train-mode graph (20 actor processes by default) for a while, killing a random actor
every minute; prints steps, recovery times, dropped messages, every process's RSS at start and
end, and whether the MCAP recording is complete.

Logic and every option: ``sdhn_experiments.bench.soak`` (``--help``).
"""

import sys

from sdhn_experiments.bench.soak import main

if __name__ == "__main__":
    sys.exit(main())
