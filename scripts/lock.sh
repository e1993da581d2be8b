#!/usr/bin/env bash
# Re-resolve the dependency lock (requirements/lock.txt) on purpose: a fresh virtualenv, the newest
# releases that pyproject.toml's ranges allow, then `pip freeze`. Review the diff, run
# `bash scripts/test.sh`, and commit the lock with a CHANGELOG line naming what moved.
#
#   bash scripts/lock.sh                    # takes a few minutes; needs the package registry
#   D5RL_LOCK_KEEP=1 bash scripts/lock.sh   # only add what is new, every pinned version kept
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
LOCK=requirements/lock.txt
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

"$PYTHON" -m venv "$TMP/venv"
PY="$TMP/venv/bin/python"
"$PY" -m pip install -q --upgrade pip setuptools wheel flit_core
# Every extra, so one lock serves users, CI and the benchmarks. torch is only the plain baseline of
# bench/agents.py (no extra asks for it); pinning it here keeps `pip install -c requirements/lock.txt torch`
# on the CPU build that lies on the development machines.
# D5RL_LOCK_KEEP=1: keep every version already pinned and resolve only what is new (a dependency added).
KEEP=(); [ "${D5RL_LOCK_KEEP:-0}" = 1 ] && KEEP=(-c "$LOCK")
"$PY" -m pip install -q --no-build-isolation "${KEEP[@]}" -e ".[train,test,export,bench]" "torch==${TORCH_VERSION:-2.13.0}"
PLATFORM="$("$PY" -c 'import platform, sys; print("CPython %d.%d on %s %s" % (*sys.version_info[:2], platform.system(), platform.machine()))')"
{
  echo "# The whole resolved dependency set of d5rl (every extra), resolved on $PLATFORM;"
  echo "# used as pip constraints by scripts/install.sh (both README commands and CI)."
  echo "# Regenerate on purpose with \`bash scripts/lock.sh\`; never edit by hand."
  # (torch's "+cpu" local label dropped: `torch==2.13.0` matches the CPU build and PyPI's alike)
  "$PY" -m pip freeze --all --exclude-editable | grep -v '^d5rl' | sed 's/+cpu$//' | LC_ALL=C sort -f
} > "$LOCK"
echo "wrote $LOCK ($(grep -vc '^#' "$LOCK") pinned packages)"
