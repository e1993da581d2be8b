"""Randomized kitchen: resets/s (new domain each reset) and 3-camera 128x128 observations/s,
as ratios against the standard kitchen measured in the same run.

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
    rnd_cold = rate(lambda i: rnd.reset(seed=i), a.resets)  # includes compiling new variants
    rnd_warm = rate(lambda i: rnd.reset(seed=i), a.resets)  # same seeds: variants cached
    std_r = rate(lambda i: std.reset(seed=i), a.resets)
    print(f"resets/s  standard {std_r:.1f} | randomized cold {rnd_cold:.2f} ({rnd_cold / std_r:.3f}x), "
          f"warm {rnd_warm:.1f} ({rnd_warm / std_r:.3f}x)")
    stdp = KitchenEnv(image_size=128)
    rndp = RandomizedKitchenEnv(image_size=128)
    stdp.reset(seed=0)
    rndp.reset(seed=0)
    act = np.zeros(9, np.float32)
    s = rate(lambda i: stdp.step(act), a.steps)
    r = rate(lambda i: rndp.step(act), a.steps)
    print(f"pixel steps/s (128x128)  standard 2 cams {s:.1f} | randomized 3 cams {r:.1f} ({r / s:.2f}x)")


if __name__ == "__main__":
    main()
