"""Env steps/s through d5rl's API vs raw ``mj_step`` of the same compiled model.

    python bench/env_overhead.py [--task a1-walk-v0] [--seconds 3]

Both sides simulate the same 50 physics steps per control step from the same
state with the same controls; the difference is d5rl's Python per step
(observation, reward terms, termination, TimeLimit wrapper).  Ratio = ours / raw.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="a1-walk-v0")
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()

    import d5rl

    env = d5rl.make_env(args.task)
    base = env.unwrapped
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, (1000, *env.action_space.shape)).astype(np.float32)

    def ours() -> int:
        env.reset(seed=0)
        n = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            _, _, term, trunc, _ = env.step(actions[n % len(actions)])
            n += 1
            if term or trunc:
                env.reset(seed=n)
        return n / (time.perf_counter() - t0)

    model = base.model
    data = mujoco.MjData(model)
    nominal = np.asarray(base.data.ctrl).copy()

    def raw() -> int:
        mujoco.mj_resetDataKeyframe(model, data, 0)
        n = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            data.ctrl[:] = nominal + 0.3 * actions[n % len(actions)]
            mujoco.mj_step(model, data, nstep=base.frame_skip)
            n += 1
        return n / (time.perf_counter() - t0)

    r_raw, r_ours = raw(), ours()
    print(f"task {args.task}: {base.frame_skip} physics steps of {model.opt.timestep * 1e3:.1f} ms per env step")
    print(f"raw mj_step (same model)  : {r_raw:8.0f} control steps/s ({r_raw * base.frame_skip:.0f} mj_step/s)")
    print(f"d5rl env.step             : {r_ours:8.0f} env steps/s")
    print(f"ratio ours/raw            : {r_ours / r_raw:.3f}  (overhead {100 * (1 - r_ours / r_raw):.1f}%)")


if __name__ == "__main__":
    main()
