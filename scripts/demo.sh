#!/usr/bin/env bash
# Set up (idempotent), then a short demo of the whole ROS stack on maif-10 with 10 robots:
#   1. train briefly (in-process trainer; exports actor weights),
#   2. deploy them through the launcher: simulator + 10 actor processes (one per robot, NumPy
#      policy) + recorder, for a few greedy episodes,
#   3. print the MCAP recording and a plot of the run.
# Knobs: TRAIN_STEPS (default 16384), EPISODES (default 3), ROS_DOMAIN_ID.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
TRAIN_STEPS="${TRAIN_STEPS:-16384}"
EPISODES="${EPISODES:-3}"
RUN_DIR="$ROOT/runs/demo-$(date +%Y%m%d-%H%M%S)"
mkdir -p "$RUN_DIR"
export ROS_LOG_DIR="$RUN_DIR/ros_logs" ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( $$ % 100 + 1 ))}"

echo "[demo] 1/3 training SDHN on maif-10 for $TRAIN_STEPS team steps (in-process trainer)"
.venv/bin/python -m sdhn_train.cli --env maif-10 --algo sdhn --seed 1 \
  --total-steps "$TRAIN_STEPS" --no-progress --set log.root="$RUN_DIR" --run-name train \
  --set eval.interval=0 --set log.tensorboard=false >"$RUN_DIR/train.log" 2>&1 \
  || { cat "$RUN_DIR/train.log"; exit 1; }
echo "[demo]     weights: $RUN_DIR/train/actor.safetensors"

# The recorder node counts as an observer the simulator waits for only once it really subscribes.
observers=true
grep -q "create_subscription" src/sdhn_sim/sdhn_sim/recorder_node.py || observers=false
echo "[demo] 2/3 deploying on maif-10: simulator + 10 actor processes + recorder, $EPISODES episodes"
scripts/launch.sh configs/launch/deploy-maif10.yaml --set weights="$RUN_DIR/train" \
  --set run_dir="$RUN_DIR/deploy" --set episodes="$EPISODES" \
  --set wait_for_observers="$observers" --set status_interval=2

echo "[demo] 3/3 results"
PLOT=$(.venv/bin/python -m sdhn_sim.launch_plot "$RUN_DIR/deploy" --train-run "$RUN_DIR/train")
MCAP="$RUN_DIR/deploy/recording.mcap"
[ -f "$MCAP" ] || MCAP="(none: the recorder in this checkout writes no file yet)"
echo "[demo] episodes: $RUN_DIR/deploy/episodes.csv"
echo "[demo] MCAP:     $MCAP"
echo "[demo] plot:     $PLOT"
