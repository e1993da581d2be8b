#!/usr/bin/env bash
# Install d5rl with its test extras into a virtualenv (.venv, every package at its locked version) and the
# robot-model assets, then run the default test suite (extra arguments go to pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/install.sh train,test
# lint and format first (settings in pyproject.toml; `ruff format .` and `ruff check --fix .` repair most findings)
ruff check --quiet .
ruff format --check --quiet .
python -m pytest -n 2 -q "$@"
