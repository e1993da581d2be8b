"""Success statistics by stage of the WidowX scripted datasets (for docs/datacards/widowx.md).

    python -m d5rl.envs.widowx.datacard_stats --episodes 200

Computes the statistics from the first N episodes of each dataset exactly as
``d5rl generate`` makes them (same generator, same per-episode seeds), without
writing anything; with ``--from-disk`` it reads the generated datasets instead.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from d5rl.datasets.generation import episode_rng, make_generator
from d5rl.registry import get_spec

TASKS = ("wx-sorting-v0", "wx-sorting-pickplacedata-v0")


def episode_metas(task_id: str, episodes: int, from_disk: bool) -> list[dict]:
    spec = get_spec(task_id)
    if from_disk:
        from d5rl.datasets.loading import load_dataset

        return list(load_dataset(task_id, episodes=episodes, generate=False).episode_meta)
    gen = make_generator(spec)
    seed = spec.dataset.default_seed
    return [gen.episode(i, episode_rng(seed, i)).meta for i in range(episodes)]


def stats(metas: list[dict]) -> dict:
    n = len(metas)
    out: dict = {"episodes": n}
    stages = max(len(m["objects"]) for m in metas)
    for s in range(stages):
        ok = [m["placed_as_intended"][s] for m in metas]
        in_a_bin = [m["final_bins"][s] is not None for m in metas]
        correct = [m["final_bins"][s] == _category(m["objects"][s]) for m in metas]
        wrong_choice = [m["wrong_bin"][s] for m in metas]
        out[f"stage {s + 1}"] = {
            "grasped (lifted off the table)": float(np.mean([m["lifted"][s] for m in metas])),
            "placed in the intended bin": float(np.mean(ok)),
            "ended in a bin": float(np.mean(in_a_bin)),
            "ended in its correct bin": float(np.mean(correct)),
            "wrong bin chosen": float(np.mean(wrong_choice)),
        }
    counts = Counter(m["num_sorted"] for m in metas)
    out["final objects sorted"] = {k: counts.get(k, 0) / n for k in (0, 1, 2)}
    out["mean final score"] = float(np.mean([m["num_sorted"] / 2 for m in metas]))
    done = [m["policy_done_step"] for m in metas if m["policy_done_step"] is not None]
    out["policy finished within the episode"] = len(done) / n
    if done:
        out["steps to finish (mean / max)"] = (float(np.mean(done)), int(np.max(done)))
    objs = Counter(o for m in metas for o in (m["domain"]["shoe"], m["domain"]["toy"]))
    out["object draws"] = dict(sorted(objs.items()))
    handled: dict[str, list[bool]] = {}
    for m in metas:
        for o, ok in zip(m["objects"], m["placed_as_intended"]):
            handled.setdefault(o, []).append(bool(ok))
    out["pick-and-place success by object"] = {o: (float(np.mean(v)), len(v)) for o, v in sorted(handled.items())}
    return out


def _category(name: str) -> str:
    from d5rl.envs.widowx.model import CATEGORY

    return CATEGORY[name]


def to_markdown(task_id: str, s: dict) -> str:
    lines = [f"### {task_id} (first {s['episodes']} episodes)", "", "| stage | grasped | grasp failed | "
             "placed in intended bin | in a bin | in its correct bin | wrong bin chosen |",
             "|---|---|---|---|---|---|---|"]
    for k, v in s.items():
        if k.startswith("stage"):
            g = v["grasped (lifted off the table)"]
            lines.append(f"| {k} | {g:.1%} | {1 - g:.1%} | {v['placed in the intended bin']:.1%} | "
                         f"{v['ended in a bin']:.1%} | {v['ended in its correct bin']:.1%} | {v['wrong bin chosen']:.1%} |")
    f = s["final objects sorted"]
    lines += ["", f"- objects in their correct bin at the end: 0: {f[0]:.1%}, 1: {f[1]:.1%}, 2: {f[2]:.1%}; "
              f"mean normalized score {s['mean final score']:.3f}",
              f"- policy finished its script within the episode: {s['policy finished within the episode']:.1%}"]
    if "steps to finish (mean / max)" in s:
        mean, mx = s["steps to finish (mean / max)"]
        lines.append(f"- steps to finish: mean {mean:.1f}, max {mx}")
    lines.append(f"- object draws: {s['object draws']}")
    per = ", ".join(f"{o} {r:.1%} (n={n})" for o, (r, n) in s["pick-and-place success by object"].items())
    lines.append(f"- pick-and-place success (placed in the intended bin) by object: {per}")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--from-disk", action="store_true", help="read the generated datasets instead of regenerating")
    args = p.parse_args(argv)
    for task in TASKS:
        print(to_markdown(task, stats(episode_metas(task, args.episodes, args.from_disk))))
        print()


if __name__ == "__main__":
    main()
