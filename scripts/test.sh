#!/usr/bin/env bash
# Set up everything (idempotent, see setup.sh) and run every quality gate:
# ruff on the whole tree, mypy on src/, the docs site (mkdocs build --strict), then pytest
# (extra arguments go to pytest).
# Tests that fail are re-run once, on their own, as a flakiness report: the output ends with a
# "[test] FLAKY" line naming every test that failed and then passed on its re-run (CI shows
# them), and a "[test] FAILED TWICE" line for those that fail the run.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
ROS_LOG_DIR="$(mktemp -d -t sdhn-roslog-XXXXXX)"
export ROS_LOG_DIR
echo "[test] ruff check"
.venv/bin/ruff check src test scripts
echo "[test] mypy on src/"
MYPYPATH=src/sdhn_base:src/sdhn_sim:src/sdhn_policy:src/sdhn_train:src/sdhn_experiments:src/sdhn_bringup .venv/bin/mypy \
  -p sdhn_base -p sdhn_sim -p sdhn_policy -p sdhn_train -p sdhn_experiments -p sdhn_bringup
echo "[test] docs: mkdocs build --strict (a broken link or a page missing from disk fails)"
SITE_DIR="$(mktemp -d -t sdhn-site-XXXXXX)"
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict --quiet --site-dir "$SITE_DIR"
rm -rf "$SITE_DIR"
echo "[test] pytest"
status=0
.venv/bin/python -m pytest "$@" || status=$?
# Exit code 1 means some tests failed; anything else (interrupted, usage error) is final.
[ "$status" -eq 1 ] || exit "$status"
LASTFAILED=.pytest_cache/v/cache/lastfailed
failed_ids() {  # node ids pytest recorded as failed in its last run, one per line
  .venv/bin/python -c 'import json, sys
try:
    print("\n".join(sorted(json.load(open(sys.argv[1])))))
except (OSError, ValueError):
    pass' "$LASTFAILED"
}
first="$(failed_ids)"
echo "[test] re-running $(echo "$first" | grep -c .) failed test(s) once, on their own:"
echo "$first" | sed 's/^/[test]   /'
status=0
.venv/bin/python -m pytest --last-failed --last-failed-no-failures none "$@" || status=$?
[ "$status" -le 1 ] || exit "$status"
again="$(failed_ids)"
flaky="$(comm -23 <(echo "$first") <(echo "$again") | grep . || true)"
if [ -n "$flaky" ]; then
  echo "[test] FLAKY (failed, then passed on the re-run): $(echo "$flaky" | grep -c .) test(s)"
  echo "$flaky" | sed 's/^/[test] FLAKY   /'
fi
if [ "$status" -ne 0 ]; then
  echo "[test] FAILED TWICE:"
  echo "$again" | sed 's/^/[test] FAILED  /'
fi
exit "$status"
