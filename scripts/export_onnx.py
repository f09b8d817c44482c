#!/usr/bin/env python3
"""Write ``actor.onnx``, its I/O contract ``actor.onnx.json`` and, for a model folder with a
``card.json``, ``deploy.json`` (observation layout, deployment mode, stall rule:
sdhn_policy.deploy_contract) next to an actor's weights.

Logic and every option: ``sdhn_policy.onnx_export_cli`` (``--help``).
"""

import sys

from sdhn_policy.onnx_export_cli import main

if __name__ == "__main__":
    sys.exit(main())
