#!/bin/bash
# Table 1 cells on a bare GPU machine with no network (docs/gpu.md): pixel cells,
# and state cells whose agents are too slow for a 2-core CPU (CQL, CalQL, FQL: 13-19 updates/s there; RLPD 5.6,
# its 20 critic updates a step):
#   STEPS=3000 BUDGET=545 bash scripts/gpu_bench.sh   # the randomized kitchen from its cameras, 100 episodes
#   CELLS="wx-sorting-v0:bc,iql:16:4 kitchen-standard-mixed-v0:iql:12:2" BUDGET=560 bash scripts/gpu_bench.sh
#   A=fql,cql,calql,idql,ddpm_bc,rebrac,iql,td3bc,bc   # WidowX from state (docs/results.md, "Table 1 from state")
#   SEEDS=0-2 STEPS=10000 CELLS="wx-sorting-state-v0:$A:16:8 wx-sorting-pickplacedata-state-v0:$A:16:8" \
#     BUDGET=520 bash scripts/gpu_bench.sh
#   CELLS="a1-walk-v0:cql,calql:2:8:final_eval_episodes=20 ..."   # A1 (state), with its 20-episode evaluation
# CELLS lists TASK:ALGOS:GENERATE_WORKERS:BENCH_WORKERS[:SET,SET...]; each entry generates its data (one
# entry at a time; a state task's without frames) and then runs its cells beside the others.  SEEDS (0-1)
# and STEPS (5000) are the grid's seeds and offline steps, or an entry's own with seeds=0-2,steps=10000
# among its SETs (pixel and state entries in one call); pixel cells also get the execution-only settings
# below.  Call it again on the same (still warm) machine to go on: packages, data and cells live in .dwork/ of
# the checkout, which .gitignore names so that the device keeps it between calls (a path ignored only in
# .git/info/exclude does not travel, and a second call would find it gone), so a second call skips
# what is done and resumes unfinished cells from their checkpoints.  LOCAL=1 skips the machine setup (a dry run
# here; CELLS and STEPS make it small).  GRID=docs/results/table1-state/cells (a grid's cells folder in the
# checkout, which travels with it) makes each entry skip the cells that grid has finished, as `d5rl bench` does
# there: `GRID=... SEEDS=0-2 STEPS=10000 CELLS="kitchen-randomized-mixed-state-v0:idql:16:4"` runs only the
# missing seeds.
# The machine needs, in the checkout (git-ignored): .gl/ (libEGL/libGL .debs), .whl/ (cp312 wheels at the lock's
# versions), .assets/ (the extracted robot models, D5RL_ASSETS): `bash scripts/gpu_prepare.sh kitchen` (or
# `kitchen wx`, or `wx`) makes them here and prints what will travel; optionally .dcache/<dataset>.json (this
# machine's manifests, to compare the regenerated data).  The working tree travels with them (64 MiB in all):
# move experiments/a1-agents/ and docs/results/table1-state/videos/ (57 MB, not used there) out of the checkout
# for the call and put them back after it.  Cells come back in $OUT/cells.tgz (split into parts under the
# device's 16 MiB a file: cat cells.tgz.part-* | tar xz) with every result file, and the checkpoints of each
# task's best finished cell (for the report's rollout GIFs) and of unfinished cells (to resume or evaluate them
# elsewhere) while they fit in 56 MiB.
T0=$(date +%s); BUDGET=${BUDGET:-540}; W=$PWD/.dwork
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
stamp() { echo "[$(( $(date +%s) - T0 ))s] $*"; }
export PYTHONUNBUFFERED=1 OUT=${OUT:-/tmp/out}; mkdir -p $OUT $W
exec > >(tee -a $OUT/log.txt) 2>&1
if [ -z "$LOCAL" ]; then
  for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
  [ -f $W/site.ok ] || { python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target $W/site .whl/*.whl && touch $W/site.ok; } || exit 3
  export PYTHONPATH=$W/site:$PWD MUJOCO_GL=egl D5RL_ASSETS=$PWD/.assets D5RL_HOME=$W/home
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader; nproc; free -g | head -2
fi
python3 -c "import jax, flax, optax, mujoco, numpy; print('versions', jax.__version__, flax.__version__, optax.__version__, mujoco.__version__, numpy.__version__, jax.devices())" || exit 4
# the default: the randomized kitchen's 4 cells side by side on the first 100 play episodes, evaluated on 50
# episodes like the other pixel rows (its family's protocol says 100: ~2 more minutes a cell on one H100)
CELLS=${CELLS:-"kitchen-randomized-mixed-v0:bc,iql:16:4:dataset_episodes=100,final_eval_episodes=50"}
# dataset_in_memory_gb: the frames are decoded into RAM once (wx-sorting: 12 GB a cell) instead of at every
# batch; checkpoint_interval: a call cut short loses at most 1,000 steps a cell; eval_processes: the final
# evaluation steps its 5 environments in 5 processes (one process could not finish 50 episodes of the randomized
# kitchen, 500 steps and 3 cameras each, in 260 s while two IQL cells trained beside it).  All are execution-only.
B="--no-report --no-progress --set checkpoint_interval=1000"
PIXELS="--set dataset_in_memory_gb=16 --set eval_processes=true"
cli() { local t=$1; shift; [ "$t" -gt 0 ] || { stamp "no time left for: $*"; return 124; }; timeout $t python3 -m d5rl.cli "$@"; }
gen() { local s=$(date +%s); cli $(( $(left) - 20 )) generate "$@" 2>&1 | tr '\r' '\n' | grep -v "it/s\|ep/s" | tail -2
        stamp "generate+render $*: $(( $(date +%s) - s )) s"; }
entry() {  # TASK ALGOS GENERATE_WORKERS BENCH_WORKERS [SET,SET...]: its data (one entry at a time), then its cells
  local sets="$PIXELS" prefix="" render="" seeds=${SEEDS:-0-1} steps=${STEPS:-5000}
  # state cells (kitchen and WidowX -state twins, A1): no frames to hold or render
  [ "$(python3 -c "from d5rl.registry import get_spec; print(get_spec('$1').observation)")" = state ] && \
    { sets=""; render="--no-render"; }
  for kv in ${5//,/ }; do
    case $kv in
      seeds=*) seeds=${kv#*=} ;;  # this entry's seeds and offline steps instead of SEEDS and STEPS
      steps=*) steps=${kv#*=} ;;
      *) sets="$sets --set $kv"; [[ $kv == dataset_episodes=* ]] && prefix="--episodes ${kv#*=}" ;;
    esac
  done
  ( flock 9; gen $1 --workers $3 $prefix $render ) 9>$W/generate.lock  # cells on a prefix of the data need only that prefix
  # the grid's finished cells of this task (results only; never over a cell resumed here) are skipped by bench
  [ -n "$GRID" ] && [ -d "$GRID/$1" ] && mkdir -p $W/cells/$1 && cp -rn "$GRID/$1" $W/cells/$1/
  cli $(( $(left) - 25 )) bench --tasks $1 --algos ${2//,/ } --seeds $seeds --offline-steps $steps $B $sets --workers $4 --out $W/cells/$1 > $W/bench-$1.log 2>&1
}
for e in $CELLS; do IFS=: read -r t a gw bw sets <<< "$e"; entry "$t" "$a" "$gw" "$bw" "$sets" & sleep 1; done
progress() { for d in $W/cells/*/*/*/seed*; do [ -d $d ] || continue; printf ' %s:%s' "$(basename $(dirname $(dirname $(dirname $d))))-$(basename $(dirname $d))$(basename $d | tr -d seed)" \
             "$( [ -f $d/done ] && echo done || (tail -n1 $d/metrics.csv 2>/dev/null | cut -d, -f1))"; done; }
while [ -n "$(jobs -r)" ]; do sleep 20; stamp "$(nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader 2>/dev/null) load $(cut -d' ' -f1 /proc/loadavg)$(progress)"; done
tail -n 3 $W/bench-*.log
for m in $W/home/datasets/*/*/manifest.json; do  # the regenerated data against this machine's, where carried
  [ -f "$m" ] || continue; d=$(basename "$(dirname "$(dirname "$m")")")
  [ -f ".dcache/$d.json" ] && python3 scripts/compare_manifests.py "$m" ".dcache/$d.json"
done
python3 - "$W/cells" <<'PY'
import csv, glob, json, os, sys
for d in sorted(glob.glob(sys.argv[1] + "/*/*/*/seed*")):
    rows = list(csv.DictReader(open(d + "/metrics.csv"))) if os.path.exists(d + "/metrics.csv") else []
    ups = [round(float(r["time/updates_per_s"]), 1) for r in rows if r.get("time/updates_per_s")]
    done = json.load(open(d + "/done")) if os.path.exists(d + "/done") else {}
    print(d, "steps", rows[-1].get("step") if rows else None, "ups", ups[-3:], "wall", done.get("wall_s"),
          "score", done.get("summary", {}).get("score"))
PY
python3 -m d5rl.runner.archive $W/cells --budget-mib 56 > $W/archive.txt  # results, then checkpoints that fit
tar cz -C $W/cells -T $W/archive.txt | split -b 15m - $OUT/cells.tgz.part- && ls -la $OUT
stamp done
