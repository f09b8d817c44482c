"""``python -m sdhn_sim.launch CONFIG.yaml`` runs :mod:`sdhn_sim.launch.supervisor`."""

import sys

from sdhn_sim.launch.supervisor import main

sys.exit(main())
