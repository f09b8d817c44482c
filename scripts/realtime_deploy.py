#!/usr/bin/env python3
"""The shipped policies deployed over ROS with the simulator's realtime clock (prints figures
and writes JSON; not a test).

Logic and every option: ``sdhn_experiments.bench.realtime_deploy`` (``--help``).
"""

import sys

from sdhn_experiments.bench.realtime_deploy import main

if __name__ == "__main__":
    sys.exit(main())
