#!/usr/bin/env bash
# Start a whole sdhn ROS graph from one YAML config (see configs/launch/ and sdhn_bringup/sdhn_bringup/supervisor.py):
#   scripts/launch.sh configs/launch/deploy-tiny.yaml --set weights=runs/<run> --set episodes=5
# Ctrl-C / SIGTERM stops every child cleanly and reports their exit codes.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
exec "$ROOT/.venv/bin/python" -m sdhn_bringup "$@"
