#!/usr/bin/env bash
# Install d5rl and the given extras into a virtualenv, every package at the version pinned in
# requirements/lock.txt, then the robot-model assets. Sourced by quickstart.sh and test.sh:
#
#   source scripts/install.sh train,test      # leaves the virtualenv activated
#
# The virtualenv is $D5RL_VENV (default: .venv in the repository), created if missing.
# Python is $PYTHON (default python3), 3.11 or newer.
set -euo pipefail
_D5RL_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_D5RL_EXTRAS="${1:-train}"
_D5RL_LOCK="$_D5RL_ROOT/requirements/lock.txt"
D5RL_VENV="${D5RL_VENV:-$_D5RL_ROOT/.venv}"
PYTHON="${PYTHON:-python3}"

if [ ! -x "$D5RL_VENV/bin/python" ]; then
  if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    echo "error: d5rl needs Python 3.11 or newer; \`$PYTHON\` is $("$PYTHON" --version 2>&1 || echo missing)" >&2
    echo "  hint: run with PYTHON=/path/to/python3.11" >&2
    exit 2
  fi
  echo "creating virtualenv $D5RL_VENV"
  "$PYTHON" -m venv "$D5RL_VENV"
fi
# shellcheck disable=SC1091
source "$D5RL_VENV/bin/activate"
export PIP_DISABLE_PIP_VERSION_CHECK=1
echo "installing d5rl[$_D5RL_EXTRAS] from $(basename "$_D5RL_LOCK") (pinned versions)"
# pip and the build backend (flit_core) first, at their locked versions; then d5rl, built with that
# backend (no build isolation: the backend is locked too).
python -m pip install -q -c "$_D5RL_LOCK" pip flit_core
python -m pip install -q -c "$_D5RL_LOCK" --no-build-isolation -e "$_D5RL_ROOT[$_D5RL_EXTRAS]"
d5rl install-assets
export MUJOCO_GL="${MUJOCO_GL:-egl}"
