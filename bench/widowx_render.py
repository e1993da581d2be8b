"""Side-camera render rate of the WidowX scene: d5rl's settings vs MuJoCo's stock settings.

    python bench/widowx_render.py [--seconds 5] [--size 128]

Both render the same scene and state at the same image size.  "stock" is the same
MjSpec compiled with MuJoCo's default visual settings (4x MSAA, 4096 shadow map,
shadow-casting lights, a 640x480 offscreen buffer); "d5rl" is the task's model
(no shadows, no MSAA, buffer sized to the image).  Also reports full env steps per
second with pixel observations and the rate of re-rendering stored states.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mujoco
import numpy as np

import d5rl  # noqa: F401  (sets MUJOCO_GL)
from bench.timing import rate
from d5rl.envs.widowx import domain as wdom
from d5rl.envs.widowx import model as wm
from d5rl.envs.widowx.data import render_states
from d5rl.envs.widowx.task import WidowXSortingEnv


def stock_model() -> mujoco.MjModel:
    spec = wm.build_spec()
    spec.visual.quality.shadowsize = 4096
    spec.visual.quality.offsamples = 4
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    for light in spec.lights:
        light.castshadow = True
    return spec.compile()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--size", type=int, default=128)
    args = p.parse_args()

    env = WidowXSortingEnv(obs_mode="state", image_size=args.size)
    env.reset(seed=0)
    state = env.get_state()
    domain = env.domain

    results = {}
    for name, model in (("stock", stock_model()), ("d5rl", wm.load_model())):
        wdom.apply_domain(model, domain)
        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(model, data)
        r = mujoco.Renderer(model, args.size, args.size)

        def render(r=r, data=data):
            r.update_scene(data, camera="side")
            r.render()

        results[name] = rate(render, args.seconds)
        r.close()

    pix = WidowXSortingEnv(obs_mode="pixels", image_size=args.size)
    pix.reset(seed=0)
    act = np.zeros(5, np.float32)
    env_fps = rate(lambda: pix.step(act), args.seconds)
    states = np.repeat(state[None], 50, axis=0)
    meta = {"domain": domain.to_json()}
    rerender = rate(lambda: render_states(states, meta, size=args.size), args.seconds) * len(states)

    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, mujoco {mujoco.__version__}"
    )
    print(f"side camera {args.size}x{args.size}:")
    print(f"  stock settings   {results['stock']:8.1f} fps")
    print(f"  d5rl settings    {results['d5rl']:8.1f} fps   ({results['d5rl'] / results['stock']:.2f}x stock)")
    print(f"  env.step (pixels obs, 50 physics steps) {env_fps:8.1f} steps/s")
    print(f"  render_states (stored states)           {rerender:8.1f} frames/s")


if __name__ == "__main__":
    main()
