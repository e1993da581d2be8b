"""Env steps/s through d5rl's API vs raw ``mj_step`` doing exactly the same physics.

    python bench/env_overhead.py [--task a1-walk-v0] [--steps 2000] [--repeats 3]

First d5rl's env runs ``--steps`` steps of random actions (resetting when an episode
ends) while the controls it sends to MuJoCo and the state after every reset are
recorded.  Then a bare ``MjData`` of the same compiled model replays them: the same
initial states, the same controls, the same number of ``mj_step`` calls, so both
sides do identical physics and the difference is d5rl's Python per step
(action scaling, observation, reward terms, termination, resets, the TimeLimit
wrapper).  Medians over alternating repeats.  Ratio = ours / raw (1.0 = no overhead).
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
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    import d5rl
    from d5rl.envs.base import STATE_SPEC

    env = d5rl.make_env(args.task)
    base = env.unwrapped
    model = base.model
    actions = np.random.default_rng(0).uniform(-1, 1, (args.steps, *env.action_space.shape)).astype(np.float32)

    def ours(record: bool):
        ctrls, starts = [], []  # starts: (step index, state) after each reset
        env.reset(seed=0)
        if record:
            starts.append((0, base.get_state()))
        t0 = time.perf_counter()
        for i in range(args.steps):
            _, _, term, trunc, _ = env.step(actions[i])
            if record:
                ctrls.append(base.data.ctrl.copy())
            if term or trunc:
                env.reset(seed=i + 1)
                if record:
                    starts.append((i + 1, base.get_state()))
        rate = args.steps / (time.perf_counter() - t0)
        return rate, np.asarray(ctrls), dict(starts)

    _, ctrls, starts = ours(record=True)
    data = mujoco.MjData(model)

    def raw() -> float:
        t0 = time.perf_counter()
        for i in range(args.steps):
            if i in starts:
                mujoco.mj_setState(model, data, starts[i], STATE_SPEC)
                mujoco.mj_forward(model, data)
            data.ctrl[:] = ctrls[i]
            mujoco.mj_step(model, data, nstep=base.frame_skip)
        return args.steps / (time.perf_counter() - t0)

    r_ours, r_raw = [], []
    for _ in range(args.repeats):
        r_raw.append(raw())
        r_ours.append(ours(record=False)[0])
    o, r = float(np.median(r_ours)), float(np.median(r_raw))
    print(
        f"task {args.task}: {base.frame_skip} physics steps of {model.opt.timestep * 1e3:.1f} ms per env step, "
        f"{args.steps} steps, {len(starts)} episodes, median of {args.repeats}"
    )
    print(f"raw mj_step, same states and controls : {r:8.0f} control steps/s ({r * base.frame_skip:.0f} mj_step/s)")
    print(f"d5rl env.step                         : {o:8.0f} env steps/s")
    print(f"ratio ours/raw                        : {o / r:.3f}  (overhead {100 * (1 - o / r):.1f}%)")


if __name__ == "__main__":
    main()
