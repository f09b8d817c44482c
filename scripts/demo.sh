#!/usr/bin/env bash
# Set up (idempotent) and run the main job: a short demo of the whole ROS stack.
# Until the ROS stack lands this starts the node graph (simulator, one actor process per robot,
# trainer, recorder) as placeholders, checks each comes up, and stops them all cleanly.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
ROBOTS="${ROBOTS:-10}"
RUN_DIR="$ROOT/runs/demo-$(date +%Y%m%d-%H%M%S)"
mkdir -p "$RUN_DIR/logs"
export ROS_LOG_DIR="$RUN_DIR/ros_logs" ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( $$ % 100 + 1 ))}"
pids=()
start() { local name=$1; shift; scripts/ros2 run "$@" >"$RUN_DIR/logs/$name.log" 2>&1 & pids+=($!); }
start sim sdhn_sim sim --ros-args -r __ns:=/sdhn
start recorder sdhn_sim recorder --ros-args -r __ns:=/sdhn
start trainer sdhn_train trainer --ros-args -r __ns:=/sdhn
for i in $(seq 0 $((ROBOTS - 1))); do
  start "actor_$i" sdhn_policy actor --ros-args -r __ns:=/sdhn/robot_$i -p robot_id:=$i
done
for _ in $(seq 100); do
  ready=$( (grep -l "ready" "$RUN_DIR"/logs/*.log 2>/dev/null || true) | wc -l)
  [ "$ready" -ge $((ROBOTS + 3)) ] && break
  sleep 0.2
done
echo "[demo] $ready of $((ROBOTS + 3)) processes ready (${ROBOTS} actors, one process each)"
kill -INT "${pids[@]}"
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=$?; done
echo "[demo] all processes stopped (worst exit code $status); logs in $RUN_DIR/logs"
exit "$status"
