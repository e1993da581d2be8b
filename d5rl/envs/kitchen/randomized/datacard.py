"""Statistics of the randomized-kitchen datasets on a sample, next to the paper's numbers.

    nice -n 5 python -m d5rl.envs.kitchen.randomized.datacard --episodes 10
"""

import argparse

import numpy as np

from d5rl.envs.kitchen.randomized.data import RandomizedKitchenGenerator

PAPER = {"demos": 4.0, "play": 3.62, "suboptimal": 3.55}


def sample_stats(mode: str, episodes: int, seed: int = 0) -> dict:
    g = RandomizedKitchenGenerator(mode=mode)
    root = np.random.SeedSequence(seed)
    metas = [g.episode(i, np.random.default_rng(s)).meta for i, s in enumerate(root.spawn(episodes))]
    solved = np.array([m["num_solved"] for m in metas])
    asked = np.array([len(m["subtasks"]) for m in metas])
    return {"episodes": episodes, "objects_per_episode": float(solved.mean()), "objects_std": float(solved.std()),
            "subtasks_asked": float(asked.mean()),
            "operators": {o: sum(m["operator"] == o for m in metas) for o in sorted({m["operator"] for m in metas})}}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--episodes", type=int, default=10)
    a = p.parse_args()
    print("| dataset | sample episodes | objects/episode (ours) | paper | subtasks asked | operators |")
    print("|---|---|---|---|---|---|")
    for mode in ("demos", "play", "suboptimal"):
        s = sample_stats(mode, a.episodes)
        print(f"| {mode} | {s['episodes']} | {s['objects_per_episode']:.2f} ± {s['objects_std']:.2f} | "
              f"{PAPER[mode]} | {s['subtasks_asked']:.2f} | {s['operators']} |")


if __name__ == "__main__":
    main()
