#!/usr/bin/env python3
"""Ship a trained actor under models/: the weights pair plus a card with what it achieves.

Logic and every option: ``sdhn_experiments.ship_model`` (``--help``).
"""

import sys

from sdhn_experiments.ship_model import main

if __name__ == "__main__":
    sys.exit(main())
