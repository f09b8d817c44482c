#!/usr/bin/env python3
"""Write the shipped MAIF instance sets to src/sdhn_sim/sdhn_sim/data/<name>.npz.

Logic and every option: ``sdhn_sim.envs.maif_instances_cli`` (``--help``).
"""

import sys

from sdhn_sim.envs.maif_instances_cli import main

if __name__ == "__main__":
    sys.exit(main())
