#!/usr/bin/env bash
# Set up (idempotent), then a short demo of the whole ROS stack on maif-10 with 10 robots, one
# actor process per robot, everything started by the launcher (scripts/launch.sh):
#   1. deploy the shipped SDHN policy (models/maif-10-sdhn) as configs/launch/deploy-maif10.yaml
#      says (greedy with stall breaking; the demo prints it from the config): simulator + 10
#      actor processes + MCAP recorder, a few episodes of completed formations (success and
#      makespan per episode),
#   2. train a short while over ROS: simulator + 10 actor processes (sampling) + trainer node,
#      which pushes new weights versions to the actors as it learns,
#   3. print the MCAP path, a plot of the runs (per-episode makespan and return) and a GIF of a
#      completed deployed episode (docs/watching-episodes.md).
# Knobs: EPISODES (default 3), TRAIN_EPISODES (default 2), MODEL (default models/maif-10-sdhn),
# TRAIN=inprocess (train with the in-process trainer instead of the trainer node), ROS_DOMAIN_ID.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
TRAIN_EPISODES="${TRAIN_EPISODES:-2}"
EPISODES="${EPISODES:-3}"
MODEL="${MODEL:-$ROOT/models/maif-10-sdhn}"
RUN_DIR="$ROOT/runs/demo-$(date +%Y%m%d-%H%M%S)"
mkdir -p "$RUN_DIR"
export ROS_LOG_DIR="$RUN_DIR/ros_logs" ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( $$ % 100 + 1 ))}"

DEPLOY=(configs/launch/deploy-maif10.yaml --set weights="$MODEL" --set run_dir="$RUN_DIR/deploy"
        --set episodes="$EPISODES" --set status_interval=5)
# How the actors act, read off the config the launcher runs (not restated here, where it could
# drift from it).
ACTIONS=$(.venv/bin/python -c 'import sys; from pathlib import Path
from sdhn_bringup.launch_config import describe_actions
from sdhn_bringup.launch_load import load_config
print(describe_actions(load_config(Path(sys.argv[1]), sys.argv[2:])))' \
  configs/launch/deploy-maif10.yaml weights="$MODEL")
echo "[demo] 1/3 deploying the shipped policy $MODEL on maif-10 (actions $ACTIONS," \
     "configs/launch/deploy-maif10.yaml): simulator + 10 actor processes + recorder," \
     "$EPISODES episodes"
sed -n '/^| who/,/^| lower/p' "$MODEL/card.md"
scripts/launch.sh "${DEPLOY[@]}"

if [ "${TRAIN:-ros}" = inprocess ]; then
  echo "[demo] 2/3 training SDHN on maif-10 in-process ($((TRAIN_EPISODES * 4096)) team steps)"
  .venv/bin/python -m sdhn_train.cli --env maif-10 --algo sdhn --seed 1 \
    --total-steps $((TRAIN_EPISODES * 4096)) --no-progress --set log.root="$RUN_DIR" \
    --run-name train --set eval.interval=0 --set log.tensorboard=false \
    >"$RUN_DIR/train.log" 2>&1 || { cat "$RUN_DIR/train.log"; exit 1; }
else
  echo "[demo] 2/3 training SDHN on maif-10 over ROS for $TRAIN_EPISODES episodes:" \
       "simulator + 10 actor processes + trainer node (from scratch; long runs: README)"
  scripts/launch.sh configs/launch/train-maif10.yaml --set run_dir="$RUN_DIR/train" \
    --set episodes="$TRAIN_EPISODES" --set recorder=false --set status_interval=5
fi

echo "[demo] 3/3 results"
PLOT=$(.venv/bin/python -m sdhn_bringup.plot "$RUN_DIR/deploy" --train-run "$RUN_DIR/train")
MCAP="$RUN_DIR/deploy/recording.mcap"
[ -f "$MCAP" ] || { echo "[demo] no recording was written"; exit 1; }
# The recording itself is plain ROS (rosbags, rosbag2 tools read it); its Foxglove copy adds the
# drawn scene, hypergraph and metrics channels.
scripts/ros2 run sdhn_sim replay "$MCAP" --add-viz --out "${MCAP%.mcap}-foxglove.mcap" >/dev/null
# The last completed deployed episode as a GIF (the last episode, said so, if none completed).
GIF="$RUN_DIR/deploy/episode.gif"
scripts/ros2 run sdhn_sim replay "$MCAP" --export-episode completed --gif "$GIF" | sed 's/^/[demo] /'
echo "[demo] summary:  scripts/ros2 run sdhn_sim replay $MCAP --summary"
echo "[demo] episodes: $RUN_DIR/deploy/episodes.csv"
echo "[demo] MCAP:     $MCAP"
echo "[demo] Foxglove: ${MCAP%.mcap}-foxglove.mcap (open it in Foxglove with configs/foxglove/sdhn_layout.json)"
echo "[demo] plot:     $PLOT"
echo "[demo] GIF:      $GIF"
