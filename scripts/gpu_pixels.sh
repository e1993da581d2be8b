#!/bin/bash
# Pixel Table 1 cells on a bare GPU machine with no network (the README's GPU trial, issue 21):
#   BUDGET=545 bash scripts/gpu_pixels.sh        (LOCAL=1: skip the machine setup, for a dry run here)
# The machine needs, in the checkout (git-ignored, prepared where pip works): .gl/ (libEGL/libGL .debs),
# .whl/ (cp312 wheels of mujoco, mujoco-core, gymnasium, zstandard, xacro, flax, optax, ...), .assets/
# (the extracted robot models, D5RL_ASSETS) and .dcache/{kitchen-standard,wx-sorting}.json (this
# machine's manifests, to compare the regenerated data). Cells come back in $OUT/cells.tgz.
T0=$(date +%s); BUDGET=${BUDGET:-540}
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
stamp() { echo "[$(( $(date +%s) - T0 ))s] $*"; }
export PYTHONUNBUFFERED=1 OUT=${OUT:-/tmp/out}; mkdir -p $OUT
exec > >(tee $OUT/log.txt) 2>&1
if [ -z "$LOCAL" ]; then
  for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
  export PYTHONPATH=/tmp/site:$PWD MUJOCO_GL=egl D5RL_ASSETS=$PWD/.assets D5RL_HOME=/tmp/d5rl
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv; nproc; free -g | head -2
fi
versions() { python3 -c "import jax, flax, optax, mujoco, numpy; print('versions', jax.__version__, flax.__version__, optax.__version__, mujoco.__version__, numpy.__version__, jax.devices())"; }
smoke() { timeout 150 python3 -m d5rl.cli train iql toy-reach-pixels-v0 --offline-steps 20 --set eval_episodes=2 --set log_interval=10 --run-dir /tmp/smoke > /tmp/smoke.log 2>&1; }
versions || exit 4
if ! smoke; then
  tail -15 /tmp/smoke.log; stamp "smoke failed with carried flax/optax: trying the image's"
  rm -rf /tmp/site/flax* /tmp/site/optax*; versions; smoke || { tail -30 /tmp/smoke.log; exit 5; }
fi
stamp "smoke ok: $(grep -o '"score": [0-9.]*' /tmp/smoke.log | tail -1)"
for t in kitchen-standard-mixed-v0 wx-sorting-v0; do
  s=$(date +%s); timeout $(( $(left) - 200 )) python3 -m d5rl.cli generate $t --workers 16 2>&1 | tr '\r' '\n' | grep -v "it/s\|ep/s" | tail -3
  stamp "generate+render $t: $(( $(date +%s) - s )) s"
done
python3 scripts/compare_manifests.py /tmp/d5rl/datasets/kitchen-standard/v1-seed0/manifest.json .dcache/kitchen-standard.json
python3 scripts/compare_manifests.py /tmp/d5rl/datasets/wx-sorting/v2-seed0/manifest.json .dcache/wx-sorting.json
du -sh /tmp/d5rl/datasets/*/*/renders/* 2>/dev/null
L=$(( $(left) - 40 )); stamp "benches with ${L}s"
B="--seeds 0-1 --offline-steps ${STEPS:-5000} --no-report --no-progress $EXTRA"
timeout $L python3 -m d5rl.cli bench --tasks kitchen-standard-mixed-v0 --algos iql $B --workers 2 --out /tmp/cells/k > /tmp/bk.log 2>&1 &
timeout $L python3 -m d5rl.cli bench --tasks wx-sorting-v0 --algos bc iql $B --workers 4 --out /tmp/cells/w > /tmp/bw.log 2>&1 &
while [ -n "$(jobs -r)" ]; do sleep 30; stamp "$(nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader 2>/dev/null) load $(cut -d' ' -f1 /proc/loadavg)"; done
tail -n 4 /tmp/bk.log /tmp/bw.log
python3 - <<'PY'
import csv, glob, json, os
for d in sorted(glob.glob("/tmp/cells/*/*/*/seed*")):
    rows = list(csv.DictReader(open(d + "/metrics.csv"))) if os.path.exists(d + "/metrics.csv") else []
    ups = [r.get("time/updates_per_s") for r in rows if r.get("time/updates_per_s")]
    done = json.load(open(d + "/done")) if os.path.exists(d + "/done") else {}
    print(d, "steps", rows[-1].get("step") if rows else None, "ups", ups[-3:], "wall", done.get("wall_s"), "score", done.get("summary", {}).get("score"))
PY
tar czf $OUT/cells.tgz --exclude='checkpoint*' --exclude='.lock' --exclude='.worker.json' -C /tmp/cells . && ls -la $OUT
stamp done
