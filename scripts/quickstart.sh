#!/usr/bin/env bash
# Install d5rl, generate a small A1 dataset, train BC on it briefly and print its normalized score.
# About 10 minutes on a 2-core laptop; everything lands in ./.venv, ./runs and ~/.cache/d5rl ($D5RL_HOME).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/install.sh train   # .venv with locked versions + robot-model assets

EPISODES="${EPISODES:-48}"
d5rl generate a1-walk-v1 --episodes "$EPISODES"     # the first 48 episodes of the full dataset
d5rl info a1-walk-v1
d5rl train bc a1-walk-v1 --offline-steps "${STEPS:-5000}" --seed 0 --run-dir runs/quickstart/bc \
  --set dataset_episodes="$EPISODES" --set eval_interval=5000 --set eval_episodes=5
d5rl eval runs/quickstart/bc   # replays the run's final evaluation from its checkpoint: the same score
