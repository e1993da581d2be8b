"""Batch sampling rate of d5rl's Dataset vs plain numpy fancy indexing of flat arrays.

    python bench/dataset_sampling.py                  # synthetic A1-sized data (200 x 400 steps, 61-D obs)
    python bench/dataset_sampling.py --task a1-walk-v0   # a generated dataset

The baseline is the D4RL way: observations/next_observations/actions/rewards/terminals
as flat in-RAM arrays indexed with one random index vector (next_observations stored
twice).  Ratios > 1 mean d5rl is faster.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def rate(fn, seconds: float) -> float:
    fn()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        fn()
        n += 1
    return n / (time.perf_counter() - t0)


def synthetic_episodes(n_eps=200, length=400, obs_dim=61, act_dim=12, seed=0):
    from d5rl.datasets.episode import Episode

    rng = np.random.default_rng(seed)
    for _ in range(n_eps):
        yield Episode({
            "observations": rng.normal(size=(length + 1, obs_dim)).astype(np.float32),
            "actions": rng.uniform(-1, 1, (length, act_dim)).astype(np.float32),
            "rewards": rng.normal(size=length).astype(np.float32),
            "terminals": np.zeros(length, bool),
            "timeouts": np.eye(1, length, length - 1, dtype=bool)[0],
        })


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task")
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args()

    from d5rl.datasets.format import ShardWriter
    from d5rl.datasets.generation import _concat
    from d5rl.datasets.dataset import ChunkedArray, Dataset
    from d5rl.datasets.loading import load_dataset

    tmp = None
    if args.task:
        ds_mem = load_dataset(args.task, generate=False, in_memory=True, progress=False)
        ds_map = load_dataset(args.task, generate=False, in_memory=False, progress=False)
        label = args.task
    else:
        eps = list(synthetic_episodes())
        ds_mem = Dataset.from_episodes(eps)
        # the same data as 13 on-disk shards, memory-mapped
        tmp = tempfile.TemporaryDirectory()
        parts: dict[str, list] = {}
        for s in range(0, len(eps), 16):
            arrays, aligns = _concat(eps[s: s + 16])
            w = ShardWriter(tmp.name, s // 16, lock_root=tmp.name)
            for k, v in arrays.items():
                w.write(k, v)
            w.commit({}, aligns)
            for k in arrays:
                parts.setdefault(k, []).append(np.load(f"{tmp.name}/shard-{s // 16:05d}/{k}.npy", mmap_mode="r"))
        ds_map = Dataset({k: ChunkedArray(v) for k, v in parts.items()}, aligns, ds_mem.episode_lengths)
        label = "synthetic 200x400, 61-D obs"

    flat = ds_mem.to_d4rl()
    keys = ["observations", "next_observations", "actions", "rewards", "terminals"]
    rng = np.random.default_rng(0)
    b = args.batch_size

    def plain():
        idx = rng.integers(0, len(flat["actions"]), b)
        return {k: flat[k][idx] for k in keys}

    r_plain = rate(plain, args.seconds)
    r_mem = rate(lambda: ds_mem.sample(b, rng), args.seconds)
    r_map = rate(lambda: ds_map.sample(b, rng), args.seconds)
    print(f"dataset: {label}; {ds_mem.num_transitions} transitions; batch {b}")
    print(f"plain numpy (flat arrays, next_obs duplicated) : {r_plain:9.0f} batches/s")
    print(f"d5rl Dataset.sample, in memory                 : {r_mem:9.0f} batches/s  ratio {r_mem / r_plain:.2f}")
    print(f"d5rl Dataset.sample, memory-mapped shards      : {r_map:9.0f} batches/s  ratio {r_map / r_plain:.2f}")
    print(f"transitions/s sampled (in memory)              : {r_mem * b:9.0f}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
