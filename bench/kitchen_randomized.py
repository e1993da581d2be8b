"""Randomized kitchen: the time of a new-domain reset (state observations) against 500 steps of the
same env (what dataset generation pays per episode), and 3-camera 128x128 observations/s against the
standard kitchen's two cameras, measured in the same run.

    nice -n 5 python bench/kitchen_randomized.py [--resets 20] [--steps 30]
"""

import argparse
import time

import numpy as np


def rate(fn, n):
    t = time.perf_counter()
    for i in range(n):
        fn(i)
    return n / (time.perf_counter() - t)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--resets", type=int, default=20)
    p.add_argument("--steps", type=int, default=30)
    a = p.parse_args()
    from d5rl.envs.kitchen.randomized.task import RandomizedKitchenEnv
    from d5rl.envs.kitchen.task import KitchenEnv

    std = KitchenEnv(obs_mode="state")
    rnd = RandomizedKitchenEnv(obs_mode="state")
    # A state environment keeps one compiled model and compiles again when the (microwave, kettle)
    # pair changes (31 of 32 new domains), so its resets cost the same every time.
    rnd_r = rate(lambda i: rnd.reset(seed=i), a.resets)
    std_r = rate(lambda i: std.reset(seed=i), a.resets)
    act = np.zeros(9, np.float32)
    rnd.reset(seed=0)
    step_r = rate(lambda i: rnd.step(act), 500)
    vs_episode = (1 / rnd_r) / (500 / step_r)
    print(
        f"resets/s  standard {std_r:.1f} | randomized (new domain) {rnd_r:.2f}; one randomized reset takes "
        f"{vs_episode:.2f}x the time of 500 of its state steps ({step_r:.0f} steps/s)"
    )
    stdp = KitchenEnv(image_size=128)
    rndp = RandomizedKitchenEnv(image_size=128)
    stdp.reset(seed=0)
    rndp.reset(seed=0)
    s = rate(lambda i: stdp.step(act), a.steps)
    r = rate(lambda i: rndp.step(act), a.steps)
    print(f"pixel steps/s (128x128)  standard 2 cams {s:.1f} | randomized 3 cams {r:.1f} ({r / s:.2f}x)")


if __name__ == "__main__":
    main()
