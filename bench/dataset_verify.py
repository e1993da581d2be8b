"""What integrity checking on load costs: ``load_dataset`` with every shard re-hashed (first load, or
after files changed), with the verification stamps (every later load), and with no check at all.

    python bench/dataset_verify.py                      # synthetic: 2 GiB of 64x64 camera frames + states
    python bench/dataset_verify.py --task a1-walk-v0    # a generated dataset (generated first if missing)

Each figure is the median of --repeats loads in this process, with the page cache warm (the files
were just written or read), so the hashing measured is CPU-bound, as on a machine with enough RAM.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def synthetic_task(gib: float):
    """A registered task whose dataset holds ~``gib`` GiB of uint8 frames (so it stays memory-mapped)."""
    from d5rl.datasets.episode import Episode
    from d5rl.registry import DatasetSpec, TaskSpec, register

    length, per_shard = 250, 16
    frame_bytes = 64 * 64 * 3 * 2  # two cameras
    episodes = max(1, int(gib * 2**30 / (frame_bytes * (length + 1))))
    return register(
        TaskSpec(
            id="bench-verify-v0",
            entry_point="tests.datasets.toy:ToyEnv",
            max_episode_steps=length,
            description="synthetic frames for bench/dataset_verify.py",
            dataset=DatasetSpec(
                name="bench-verify",
                version=1,
                generator="bench.dataset_verify:FrameGenerator",
                num_episodes=episodes,
                episodes_per_shard=per_shard,
                generator_kwargs={"length": length},
            ),
        )
    ), Episode


class FrameGenerator:
    version = "1"

    def __init__(self, task_id, length):
        self.length = length

    def episode(self, index, rng):
        from d5rl.datasets.episode import Episode

        t = self.length
        frames = rng.integers(0, 255, (t + 1, 64, 64, 3), dtype=np.uint8)
        return Episode(
            {
                "observations/pixels/a": frames,
                "observations/pixels/b": frames[::-1].copy(),
                "observations/proprio": rng.normal(size=(t + 1, 9)).astype(np.float32),
                "states": rng.normal(size=(t + 1, 60)),
                "actions": rng.uniform(-1, 1, (t, 9)).astype(np.float32),
                "rewards": np.zeros(t, np.float32),
                "terminals": np.zeros(t, bool),
                "timeouts": np.eye(1, t, t - 1, dtype=bool)[0],
            },
            {},
        )


def timed(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task")
    ap.add_argument("--gib", type=float, default=2.0, help="size of the synthetic dataset")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    from d5rl.datasets import format as fmt
    from d5rl.datasets.generation import dataset_root, dataset_spec
    from d5rl.datasets.loading import load_dataset

    tmp = None
    if args.task:
        task = args.task
    else:
        tmp = tempfile.TemporaryDirectory()
        os.environ["D5RL_HOME"] = tmp.name
        task, _ = synthetic_task(args.gib)
    ds = load_dataset(task, progress=True)  # generates if missing
    root = dataset_root(dataset_spec(task))
    size = sum(p.stat().st_size for p in (root / "shards").rglob("*.npy"))

    def load():
        return load_dataset(task, generate=False, progress=False)

    def unstamped():
        for stamp in root.rglob(fmt.STAMP):
            stamp.unlink()
        fmt._STAMP_MEMO.clear()
        return load()

    real_check = fmt.check_shard
    t_hash = timed(unstamped, args.repeats)
    t_stamp = timed(load, args.repeats)
    fmt.check_shard = lambda shard_dir, record: []  # what loading cost before integrity checks
    try:
        t_none = timed(load, args.repeats)
    finally:
        fmt.check_shard = real_check
    print(
        f"dataset: {ds.metadata.get('task_id')}; {ds.num_episodes} episodes, {len(list((root / 'shards').iterdir()))} "
        f"shards, {size / 2**30:.2f} GiB of arrays"
    )
    print(f"load, no integrity check (baseline)     : {t_none * 1e3:9.1f} ms")
    print(f"load, verification stamps (every load)  : {t_stamp * 1e3:9.1f} ms   ratio {t_stamp / t_none:.2f}")
    print(
        f"load, every shard re-hashed (first load): {t_hash * 1e3:9.1f} ms   ratio {t_hash / t_none:.2f}  "
        f"({size / 2**20 / max(t_hash - t_none, 1e-9):.0f} MiB/s hashed)"
    )
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
