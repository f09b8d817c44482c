"""``python -m sdhn_bringup CONFIG.yaml`` runs :mod:`sdhn_bringup.supervisor`."""

import sys

from sdhn_bringup.supervisor import main

sys.exit(main())
