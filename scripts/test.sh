#!/usr/bin/env bash
# Set up everything (idempotent, see setup.sh) and run every quality gate:
# ruff on the whole tree, mypy on src/, then pytest (extra arguments go to pytest).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
ROS_LOG_DIR="$(mktemp -d -t sdhn-roslog-XXXXXX)"
export ROS_LOG_DIR
echo "[test] ruff check"
.venv/bin/ruff check src test scripts
echo "[test] mypy on src/"
MYPYPATH=src/sdhn_sim:src/sdhn_policy:src/sdhn_train .venv/bin/mypy \
  -p sdhn_sim -p sdhn_policy -p sdhn_train
echo "[test] pytest"
exec .venv/bin/python -m pytest "$@"
