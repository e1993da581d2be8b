"""BC on parts of a1-locomotion: which episodes make BC stand still on a1-walk-v0?

    python experiments/a1-bc-subsets/bc_subsets.py [--seeds 0 1 2] [--steps 10000]

BC (d5rl's agent and settings for A1: actor lr 1e-3, 256x256, state-dependent std) trained on
the episodes of the dataset whose snapshot segment is at least K (segment 0: uniform random
actions before learning; 1, 2, ...: the snapshots in training order, see the A1 data card), then
evaluated on 10 episodes of a1-walk-v0 (deterministic mean action).  Prints a Markdown table of
the normalized score and mean forward speed per subset, mean +- std over seeds.
"""

from __future__ import annotations

import argparse

import numpy as np


def train_bc(observations, actions, seed: int, steps: int):
    from d5rl.agents.bc import BCAgent
    from d5rl.settings import resolve

    cfg = resolve("bc", "a1-walk-v0", offline_steps=steps).agent  # the settings `d5rl train` uses
    agent = BCAgent.create(seed, observations[:1], actions[:1], cfg)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        b = rng.integers(0, len(observations), cfg.batch_size)
        agent, _ = agent.update({"observations": observations[b], "actions": actions[b]})
    return agent


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--min-segments", type=int, nargs="+", default=[0, 1, 2, 3, 5])
    args = ap.parse_args(argv)

    from d5rl.datasets.loading import load_dataset
    from d5rl.training.evaluation import evaluate

    ds = load_dataset("a1-walk-v0", progress=False)
    obs, act = np.asarray(ds.observations), np.asarray(ds.arrays["actions"])
    segment = np.array([m["segment"] for m in ds.episode_meta])
    print(f"a1-locomotion v{ds.metadata['dataset_version']}, BC {args.steps} steps, seeds {args.seeds}, "
          "10 evaluation episodes of a1-walk-v0 per seed\n")
    print("| episodes used | episodes | transitions | normalized score | mean forward speed (m/s) |")
    print("|---|---:|---:|---|---|")
    for k in args.min_segments:
        sel = np.flatnonzero(segment >= k)
        rows = np.flatnonzero(segment[ds.transition_episode] >= k)  # their transitions
        scores, speeds = [], []
        for seed in args.seeds:
            r = evaluate(train_bc(obs[rows], act[rows], seed, args.steps), "a1-walk-v0", 10, seed=seed)
            scores.append(r["score"])
            speeds.append(r["stats"]["forward_speed"])
        what = "all" if k == 0 else f"segment >= {k}"
        print(f"| {what} | {len(sel)} | {len(rows):,} | {np.mean(scores):.3f} ± {np.std(scores):.3f} "
              f"| {np.mean(speeds):.2f} ± {np.std(speeds):.2f} |", flush=True)


if __name__ == "__main__":
    main()
