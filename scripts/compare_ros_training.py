#!/usr/bin/env python3
"""Does training over ROS learn like training in process? (issue 15)

Logic and every option: ``sdhn_experiments.bench.ros_vs_inprocess`` (``--help``).
"""

import sys

from sdhn_experiments.bench.ros_vs_inprocess import main

if __name__ == "__main__":
    sys.exit(main())
