#!/usr/bin/env python3
"""Add the large held-out set to a shipped MAIF model's card: greedy play and, with
``--temperature T``, sampled play at T, with ``--break-stalls [RULE]`` greedy play with stall
breaking (``sdhn_policy.stall_breaker``), on the 1,000 instances on 200 maps no training run
sees; the card recommends the mode its launch config deploys (``--deploy``; default: the last
one evaluated of greedy, sampled, break-stalls).

Logic and every option: ``sdhn_experiments.card_heldout`` (``--help``).
"""

import sys

from sdhn_experiments.card_heldout import main

if __name__ == "__main__":
    sys.exit(main())
