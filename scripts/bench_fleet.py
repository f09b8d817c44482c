#!/usr/bin/env python3
"""The fleet cost curve (prints figures; not a test): whole deploy graphs started by the launcher
at N robots, one actor process per robot or actor hosts, simple discovery or the Fast DDS
discovery server.

Logic and every option: ``sdhn_experiments.bench.fleet`` (``--help``).
"""

import sys

from sdhn_experiments.bench.fleet import main

if __name__ == "__main__":
    sys.exit(main())
