"""Updates per second of every d5rl agent vs. a plain PyTorch (eager) version of the
same algorithm, networks and batch, measured in the same run.

    python bench/agents.py                       # all agents, state and pixels
    python bench/agents.py --agents iql td3bc --no-pixels --seconds 5

State: batch 256, 58-D observations, 12-D actions (A1-sized).  Pixels: batch 64,
two 64×64 cameras with 3 stacked frames (18 channels) + 9-D proprioception,
9-D actions, IMPALA encoders, DrQ augmentation.  RLPD runs UTD 20 (one update =
20 critic steps + 1 actor step) in both implementations.

JAX is timed as the training loop runs it: state agents do ``updates_per_call``
updates per jit call with ``lax.scan``; pixel agents one per call.  JAX runs with the
XLA flags ``import d5rl`` sets (d5rl/xla_flags.py; set them in ``XLA_FLAGS`` to compare).
Numbers are medians over alternating repeats (the machine may be shared).  Without torch
the reference column is empty.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time

import numpy as np
from torch_reference import torch_runner  # bench/torch_reference.py: the plain PyTorch baselines

OBS_DIM, ACT_DIM, BATCH = 58, 12, 256
PIX, CAMS, STACK, PROPRIO, PIX_ACT, PIX_BATCH = 64, 2, 3, 9, 9, 64
KEYS = ("observations", "actions", "rewards", "masks", "next_observations", "mc_returns", "next_actions")


# ============================== data ==============================
def make_batch(n: int, pixels: bool, rng: np.random.Generator) -> dict:
    if pixels:

        def obs():
            o = {f"pixels/cam{i}": rng.integers(0, 256, (n, PIX, PIX, 3 * STACK), dtype=np.uint8) for i in range(CAMS)}
            o["proprio"] = rng.standard_normal((n, PROPRIO)).astype(np.float32)
            return o

        a_dim = PIX_ACT
    else:

        def obs():
            return rng.standard_normal((n, OBS_DIM)).astype(np.float32)

        a_dim = ACT_DIM
    return {
        "observations": obs(),
        "next_observations": obs(),
        "actions": rng.uniform(-0.99, 0.99, (n, a_dim)).astype(np.float32),
        "rewards": rng.standard_normal(n).astype(np.float32),
        "masks": (rng.random(n) > 0.01).astype(np.float32),
        "mc_returns": rng.standard_normal(n).astype(np.float32),
        "next_actions": rng.uniform(-0.99, 0.99, (n, a_dim)).astype(np.float32),
    }


# ============================== JAX side ==============================
def jax_runner(name: str, pixels: bool, k: int):
    import jax

    from d5rl.agents import get_agent

    cls, get_config = get_agent(name)
    cfg = get_config()
    if pixels:
        cfg = cfg.replace(batch_size=PIX_BATCH)
    utd = cfg.get("utd_ratio", 1)
    per = cfg.batch_size * utd
    rng = np.random.default_rng(0)
    ex = make_batch(1, pixels, rng)
    agent = cls.create(0, ex["observations"], ex["actions"], cfg)
    k = 1 if pixels else k
    batches = [make_batch(per * k, pixels, rng) for _ in range(2)]
    if k > 1:
        batches = [jax.tree_util.tree_map(lambda x: x.reshape((k, per) + x.shape[1:]), b) for b in batches]
        step = lambda a, b: a.update_many(b)  # noqa: E731
    else:
        step = lambda a, b: a.update_donated(b)  # noqa: E731
    state = {"agent": agent, "i": 0}

    def run(n_calls: int) -> int:
        a = state["agent"]
        for _ in range(n_calls):
            a, m = step(a, batches[state["i"] % 2])
            state["i"] += 1
        jax.block_until_ready(m)
        state["agent"] = a
        return n_calls * k

    return run


# ============================== timing ==============================
def rate(run, seconds: float) -> float:
    """Updates per second: run in growing chunks until ``seconds`` have passed."""
    n_calls, done, t0 = 1, 0, time.perf_counter()
    while True:
        done += run(n_calls)
        el = time.perf_counter() - t0
        if el >= seconds:
            return done / el
        n_calls = max(1, min(n_calls * 2, int(n_calls * seconds / max(el, 1e-3))))


def main(argv=None) -> int:
    from d5rl.agents import AGENTS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agents", nargs="*", default=list(AGENTS))
    p.add_argument("--no-pixels", action="store_true")
    p.add_argument("--no-state", action="store_true")
    p.add_argument("--seconds", type=float, default=4.0, help="per measurement")
    p.add_argument("--repeats", type=int, default=3, help="alternating JAX / torch repeats (median)")
    p.add_argument("--updates-per-call", type=int, default=8, help="lax.scan length for state agents")
    p.add_argument(
        "--torch-threads",
        type=int,
        default=0,
        help="torch intra-op threads; 0 = try 1 and all CPUs per case and keep the faster",
    )
    args = p.parse_args(argv)
    try:
        import torch

        ref_name = f"torch {torch.__version__} eager"
    except ImportError:
        torch = None
        ref_name = None
    import jax

    print(
        f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jax {jax.__version__} "
        f"({jax.default_backend()}), reference: {ref_name or 'none (torch not installed)'}"
    )
    print(f"{'agent':10s} {'obs':6s} {'jax upd/s':>10s} {'torch upd/s':>12s} {'ratio':>6s} {'torch thr':>9s}")
    kinds = ([False] if not args.no_state else []) + ([True] if not args.no_pixels else [])
    worst = math.inf
    for pixels in kinds:
        for name in args.agents:
            jr = jax_runner(name, pixels, args.updates_per_call)
            jr(1)  # compile
            tr = torch_runner(name, pixels, make_batch, PIX_BATCH if pixels else BATCH) if torch is not None else None
            threads = args.torch_threads
            if tr is not None:
                tr(1)
                if not threads:  # give the reference its best thread count on this (possibly shared) machine
                    trial = {}
                    for n in sorted({1, os.cpu_count() or 1}):
                        torch.set_num_threads(n)
                        trial[n] = rate(tr, min(1.0, args.seconds))
                    threads = max(trial, key=trial.get)
                torch.set_num_threads(threads)
            js, ts = [], []
            for _ in range(args.repeats):
                js.append(rate(jr, args.seconds))
                if tr is not None:
                    ts.append(rate(tr, args.seconds))
            j = statistics.median(js)
            t = statistics.median(ts) if ts else float("nan")
            ratio = j / t if ts else float("nan")
            worst = min(worst, ratio) if ts else worst
            print(
                f"{name:10s} {'pixels' if pixels else 'state':6s} {j:10.1f} {t:12.1f} {ratio:6.2f} {threads:9d}",
                flush=True,
            )
    if math.isfinite(worst):
        print(f"# slowest ratio: {worst:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
