"""Pixel training steps with batches gathered ahead in background threads (the training loop's
``Prefetcher``) vs gathered inline before each update, measured in the same run.

    nice -n 5 python bench/pixel_loop.py                       # kitchen-standard-mixed-v0, BC, 60 episodes
    python bench/pixel_loop.py --task wx-sorting-v0 --algo iql --episodes 100

Loads the first episodes of a pixel task's generated dataset (frames decoded into RAM, as with
``--set dataset_in_memory_gb``), builds the agent with the task's resolved settings, and times
``--steps`` updates the way the offline loop runs them (update, then read the metrics back): once
with each batch sampled inline, once from a ``Prefetcher``; alternating repeats, medians.  Also
times one batch's sampling and one update alone: gathering ahead can at best hide the smaller of
the two.  Ratio > 1: gathering ahead is faster.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="kitchen-standard-mixed-v0")
    p.add_argument("--algo", default="bc")
    p.add_argument("--episodes", type=int, default=60)
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()

    import jax

    from d5rl import load_dataset
    from d5rl.agents import get_agent
    from d5rl.settings import resolve
    from d5rl.training.parts import Prefetcher, Sampler

    settings = resolve(args.algo, args.task, offline_steps=args.steps)
    cls = get_agent(settings.algo)[0]
    ds = load_dataset(args.task, episodes=args.episodes, in_memory=True, generate=False, progress=False)
    cfg = cls.fit_config(settings.agent, ds)
    sampler = Sampler(ds, settings.train.frame_stack, cls.extra_batch_keys, cfg.get("discount", 0.99))
    example = sampler.sample(1, np.random.default_rng(0))
    agent = cls.create(0, example["observations"], example["actions"], cfg)
    n = agent.samples_per_update()

    def steps(agent, next_batch):
        for _ in range(args.steps):
            agent, info = agent.update_donated(next_batch())
            jax.device_get(info)
        return agent

    rng = np.random.default_rng(1)
    inline_batch = lambda: sampler.sample(n, rng)  # noqa: E731
    agent = steps(agent, inline_batch)  # compile
    inline, ahead, sample_s, update_s = [], [], [], []
    for _ in range(args.repeats):
        t = time.perf_counter()
        agent = steps(agent, inline_batch)
        inline.append((time.perf_counter() - t) / args.steps)
        t = time.perf_counter()
        with Prefetcher(sampler, n, rng) as batches:
            agent = steps(agent, batches.next)
        ahead.append((time.perf_counter() - t) / args.steps)
        t = time.perf_counter()
        for _ in range(5):
            b = sampler.sample(n, rng)
        sample_s.append((time.perf_counter() - t) / 5)
        t = time.perf_counter()
        for _ in range(5):
            agent, info = agent.update_donated(b)
            jax.device_get(info)
        update_s.append((time.perf_counter() - t) / 5)
    med = statistics.median
    print(
        f"{args.task} {settings.algo} batch {n}, {jax.devices()[0].platform}, {os.cpu_count()} cores: "
        f"sample {med(sample_s) * 1e3:.0f} ms, update {med(update_s) * 1e3:.0f} ms; step inline "
        f"{med(inline) * 1e3:.0f} ms, gathered ahead {med(ahead) * 1e3:.0f} ms"
    )
    print(f"gathered ahead vs inline: {med(inline) / med(ahead):.2f}x")


if __name__ == "__main__":
    main()
