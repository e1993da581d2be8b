"""Batch sampling rate of d5rl's Dataset vs plain numpy fancy indexing of flat arrays, and the
storage and sampling cost of compressed camera frames.

    python bench/dataset_sampling.py                  # synthetic A1-sized data (200 x 400 steps, 61-D obs)
    python bench/dataset_sampling.py --task a1-walk-v0   # a generated dataset
    nice -n 5 python bench/dataset_sampling.py --pixels  # randomized-kitchen frames, compressed

The baseline is the D4RL way: observations/next_observations/actions/rewards/terminals
as flat in-RAM arrays indexed with one random index vector (next_observations stored
twice).  Ratios > 1 mean d5rl is faster.

``--pixels`` renders a few randomized-kitchen episodes (3 cameras, 128x128, new domains), stores
their frames as the render cache does (:mod:`d5rl.datasets.chunks`) and prints two ratios:
compressed / raw size (target <= 0.2), and the time of one pixel BC update (batch 64, 3 stacked
frames of 3 cameras + proprioception, d5rl's JAX agent) over the time to sample such a batch
(target >= 10), each the median of alternating repeats (the machine may be shared).  Frames held
raw in RAM are timed too, for reference.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench.timing import rate


def synthetic_episodes(n_eps=200, length=400, obs_dim=61, act_dim=12, seed=0):
    from d5rl.datasets.episode import Episode

    rng = np.random.default_rng(seed)
    for _ in range(n_eps):
        yield Episode(
            {
                "observations": rng.normal(size=(length + 1, obs_dim)).astype(np.float32),
                "actions": rng.uniform(-1, 1, (length, act_dim)).astype(np.float32),
                "rewards": rng.normal(size=length).astype(np.float32),
                "terminals": np.zeros(length, bool),
                "timeouts": np.eye(1, length, length - 1, dtype=bool)[0],
            }
        )


def kitchen_frames(episodes: int, seed: int = 0):
    """Frames (3 cameras, 128x128) of ``episodes`` randomized-kitchen play episodes, their lengths."""
    from d5rl.envs.kitchen.randomized import data as rd

    gen = rd.RandomizedKitchenGenerator(mode="play")
    frames, lengths, proprio = {}, [], []
    for i, s in enumerate(np.random.SeedSequence(seed).spawn(episodes)):
        ep = gen.episode(i, np.random.default_rng(s))
        for k, v in rd.render_episode(ep.arrays, ep.meta).items():
            frames.setdefault(k, []).append(v)
        lengths.append(ep.num_transitions)
        proprio.append(ep.arrays["observations/proprio"])
    return {k: np.concatenate(v) for k, v in frames.items()}, lengths, np.concatenate(proprio)


def pixel_update_timer(cameras: int, size: int, stack: int, batch: int, repeats: int = 3):
    """A function returning the median time of ``repeats`` pixel BC updates of d5rl's JAX agent on
    such a batch (compiled once, here)."""
    import statistics

    import jax

    from d5rl.agents import get_agent

    cls, get_config = get_agent("bc")
    rng = np.random.default_rng(0)

    def obs(n):
        o = {f"pixels/cam{i}": rng.integers(0, 256, (n, size, size, 3 * stack), dtype=np.uint8) for i in range(cameras)}
        o["proprio"] = rng.standard_normal((n, 9)).astype(np.float32)
        return o

    cfg = get_config().replace(batch_size=batch)
    agent = cls.create(0, obs(1), np.zeros((1, 9), np.float32), cfg)
    b = {
        "observations": obs(batch),
        "next_observations": obs(batch),
        "actions": rng.uniform(-1, 1, (batch, 9)).astype(np.float32),
        "rewards": np.zeros(batch, np.float32),
        "masks": np.ones(batch, np.float32),
    }
    state = {"agent": agent}

    def timed() -> float:
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            state["agent"], m = state["agent"].update(b)
            jax.block_until_ready(m)
            times.append(time.perf_counter() - t)
        return statistics.median(times)

    timed()  # compile
    return timed


def pixels(args) -> None:
    from d5rl.datasets import chunks
    from d5rl.datasets.dataset import Dataset

    t = time.perf_counter()
    frames, lengths, proprio = kitchen_frames(args.episodes)
    render_s = time.perf_counter() - t
    raw = sum(v.nbytes for v in frames.values())
    tmp = tempfile.TemporaryDirectory()
    arrays, packed = {}, 0
    t = time.perf_counter()
    for key, v in frames.items():
        path = os.path.join(tmp.name, key.replace("/", ".") + chunks.SUFFIX)
        chunks.compress_array(path, v, [n + 1 for n in lengths])
        packed += os.path.getsize(path)
        arrays[key] = chunks.CompressedArray(path)
    compress_s = time.perf_counter() - t
    n = sum(lengths)
    rng = np.random.default_rng(0)
    common = {
        "actions": rng.uniform(-1, 1, (n, 9)).astype(np.float32),
        "rewards": np.zeros(n, np.float32),
        "terminals": np.zeros(n, bool),
        "timeouts": np.zeros(n, bool),
        "observations/proprio": proprio,
    }
    aligns = {k: "transition" for k in ("actions", "rewards", "terminals", "timeouts")}
    aligns.update({k: "step" for k in (*frames, "observations/proprio")})
    ds = Dataset({**common, **arrays}, aligns, np.array(lengths))
    ds_raw = Dataset({**common, **frames}, aligns, np.array(lengths))

    def sample(d):
        return lambda: d.sample(args.pixel_batch, rng, frame_stack=3)

    import statistics

    update = pixel_update_timer(len(frames), frames[next(iter(frames))].shape[1], 3, args.pixel_batch)
    packed_t, raw_t, update_t = [], [], []
    for _ in range(args.repeats):  # alternate: load on a shared machine changes within seconds
        packed_t.append(1.0 / rate(sample(ds), args.seconds))
        raw_t.append(1.0 / rate(sample(ds_raw), args.seconds))
        update_t.append(update())
    packed_s, raw_s, update_s = (statistics.median(x) for x in (packed_t, raw_t, update_t))
    frames_n = sum(len(v) for v in frames.values())
    print(
        f"randomized kitchen: {len(lengths)} play episodes, {frames_n} frames (3 cameras, 128x128), "
        f"rendered at {frames_n / render_s:.0f} frames/s; compressed at {raw / compress_s / 1e6:.0f} MB/s"
    )
    print(
        f"raw {raw / 1e6:.1f} MB -> compressed {packed / 1e6:.1f} MB: size ratio {packed / raw:.3f} "
        f"({raw / packed:.2f}x smaller; target ratio <= 0.2)"
    )
    print(
        f"pixel batch (batch {args.pixel_batch}, 3 stacked frames, {len(frames)} cameras, obs + next obs): "
        f"compressed {1e3 * packed_s:.1f} ms | raw in RAM {1e3 * raw_s:.1f} ms"
    )
    print(f"pixel BC update (same batch shape, d5rl JAX): {1e3 * update_s:.0f} ms")
    print(
        f"update / sample time: {update_s / packed_s:.1f}x (compressed), {update_s / raw_s:.1f}x (raw); "
        f"target >= 10 (medians of {args.repeats} alternating repeats)"
    )
    tmp.cleanup()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task")
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--pixels", action="store_true", help="compressed randomized-kitchen frames (see above)")
    ap.add_argument("--episodes", type=int, default=4, help="--pixels: episodes to render")
    ap.add_argument("--pixel-batch", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3, help="--pixels: alternating repeats (median)")
    args = ap.parse_args()
    if args.pixels:
        return pixels(args)

    from d5rl.datasets.dataset import ChunkedArray, Dataset
    from d5rl.datasets.format import ShardWriter
    from d5rl.datasets.generation import _concat
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
            arrays, aligns = _concat(eps[s : s + 16])
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
