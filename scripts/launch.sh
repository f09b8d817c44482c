#!/usr/bin/env bash
# Start a whole sdhn ROS graph from one YAML config (see configs/launch/ and sdhn_bringup/sdhn_bringup/supervisor.py):
#   scripts/launch.sh configs/launch/deploy-tiny.yaml --set weights=runs/<run> --set episodes=5
# Ctrl-C / SIGTERM stops every child cleanly and reports their exit codes.
# Relative paths (the config, weights, run_dir, also inside the config) are the caller's: from
# the current directory, as with any command; this script never changes directory.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
exec "$ROOT/.venv/bin/python" -m sdhn_bringup "$@"
