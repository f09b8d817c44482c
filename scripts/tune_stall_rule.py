#!/usr/bin/env python3
"""Choose a shipped MAIF model's stall rule on the validation set, then report it once on the
large held-out set: the rule is chosen on 1,000 instances (200 maps) that neither training nor
the reported figures use, so the held-out figures are not tuned on the set they report.

Logic and every option: ``sdhn_experiments.stall_rule_cli`` (``--help``).
"""

import sys

from sdhn_experiments.stall_rule_cli import main

if __name__ == "__main__":
    sys.exit(main())
