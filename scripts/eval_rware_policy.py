#!/usr/bin/env python3
"""An exported RWARE actor, greedy, on any RWARE task: deliveries per episode (zero-shot on a
team size it was not trained on, its one-hot robot ids moved to the new team as warm start moves
them: ``sdhn_policy.team_size.for_team``).

Logic and every option: ``sdhn_experiments.rware_policy_eval`` (``--help``).
"""

import sys

from sdhn_experiments.rware_policy_eval import main

if __name__ == "__main__":
    sys.exit(main())
