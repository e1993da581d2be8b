"""Success statistics by stage of the WidowX scripted datasets (for docs/datacards/widowx.md).

    python -m d5rl.production.widowx.datacard_stats --episodes 200 [--task wx-sorting-v0]
    python -m d5rl.production.widowx.datacard_stats --frames docs/img/widowx-first-frames.png

Computes the statistics from the first N episodes of each dataset exactly as
``d5rl generate`` makes them (same generator, same per-episode seeds), without
writing anything; with ``--from-disk`` it reads the generated datasets instead.
``--frames PNG`` writes the first camera frame of the first 8 ``wx-sorting`` episodes
as a 4 x 2 grid instead (the data card's picture of the scene and its variation).
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from d5rl.datasets.generation import episode_rng, make_generator
from d5rl.datasets.loading import load_dataset
from d5rl.envs.widowx.data import render_states
from d5rl.envs.widowx.model import CATEGORY
from d5rl.registry import get_spec

TASKS = ("wx-sorting-v0", "wx-sorting-pickplacedata-v0")


def episode_metas(task_id: str, episodes: int, from_disk: bool) -> list[dict]:
    spec = get_spec(task_id)
    if from_disk:
        return list(load_dataset(task_id, episodes=episodes, generate=False, render=False).episode_meta)
    gen = make_generator(spec)
    seed = spec.dataset.default_seed
    return [gen.episode(i, episode_rng(seed, i)).meta for i in range(episodes)]


def stats(metas: list[dict]) -> dict:
    n = len(metas)
    out: dict = {"episodes": n}
    stages = max(len(m["objects"]) for m in metas)
    for s in range(stages):
        ms = [m for m in metas if len(m["objects"]) > s]
        out[f"stage {s + 1}"] = {
            "episodes": len(ms),
            "grasped (lifted off the table)": _mean(m["lifted"][s] for m in ms),
            "placed in the intended bin": _mean(m["placed_as_intended"][s] for m in ms),
            "ended in a bin": _mean(m["final_bins"][s] is not None for m in ms),
            "ended in its correct bin": _mean(m["final_bins"][s] == _category(m["objects"][s]) for m in ms),
            "wrong bin chosen": _mean(m["wrong_bin"][s] for m in ms),
        }
    counts = Counter(m["num_sorted"] for m in metas)
    out["final objects sorted"] = {k: counts.get(k, 0) / n for k in (0, 1, 2)}
    out["full task solved"] = counts.get(2, 0) / n
    out["mean final score"] = float(np.mean([m["num_sorted"] / 2 for m in metas]))
    # segments: each object in its own bin at the end, counted over all episodes
    for cat in ("shoe", "toy"):
        out[f"{cat} in the {cat} bin at the end"] = _mean(m["end_bins"][cat] == cat for m in metas)
    attempts = [(m, i) for m in metas for i in range(len(m["objects"]))]
    real = [(m, i) for m, i in attempts if not m.get("missed_grasp", [False] * 2)[i]]
    out["objects attempted"] = len(attempts)
    out["grasp failures (not lifted), of real grasps"] = (_mean(not m["lifted"][i] for m, i in real), len(real))
    out["botched grasps (on purpose)"] = len(attempts) - len(real)
    out["wrong bin chosen, of attempted objects"] = _mean(m["wrong_bin"][i] for m, i in attempts)
    out["ended in the wrong bin, of attempted objects"] = _mean(
        m["final_bins"][i] not in (None, _category(m["objects"][i])) for m, i in attempts
    )
    plans = Counter(m.get("plan", "both") for m in metas)
    out["plans"] = {
        p: (c / n, _mean(m["num_sorted"] == 2 for m in metas if m.get("plan", "both") == p))
        for p, c in sorted(plans.items())
    }
    done = [m["policy_done_step"] for m in metas if m["policy_done_step"] is not None]
    out["policy finished within the episode"] = len(done) / n
    if done:
        out["steps to finish (mean / max)"] = (float(np.mean(done)), int(np.max(done)))
    objs = Counter(o for m in metas for o in (m["domain"]["shoe"], m["domain"]["toy"]))
    out["object draws"] = dict(sorted(objs.items()))
    handled: dict[str, list[bool]] = {}
    for m, i in real:
        handled.setdefault(m["objects"][i], []).append(bool(m["placed_as_intended"][i]))
    out["pick-and-place success by object"] = {o: (float(np.mean(v)), len(v)) for o, v in sorted(handled.items())}
    return out


def _mean(xs) -> float:
    xs = [bool(x) for x in xs]
    return float(np.mean(xs)) if xs else float("nan")


def _category(name: str) -> str:
    return CATEGORY[name]


def to_markdown(task_id: str, s: dict) -> str:
    lines = [
        f"### {task_id} ({s['episodes']} episodes)",
        "",
        f"- full task solved (both objects in their correct bins at the end): {s['full task solved']:.1%}",
        f"- shoe in the shoe bin at the end: {s['shoe in the shoe bin at the end']:.1%} of episodes; "
        f"toy in the toy bin: {s['toy in the toy bin at the end']:.1%}",
        f"- objects in their correct bin at the end: 0: {s['final objects sorted'][0]:.1%}, "
        f"1: {s['final objects sorted'][1]:.1%}, 2: {s['final objects sorted'][2]:.1%}; "
        f"mean normalized score {s['mean final score']:.3f}",
    ]
    g, ng = s["grasp failures (not lifted), of real grasps"]
    lines += [
        f"- objects attempted: {s['objects attempted']}; grasp failures: {g:.1%} of {ng} real grasps; "
        f"botched on purpose: {s['botched grasps (on purpose)']}",
        f"- wrong bin chosen: {s['wrong bin chosen, of attempted objects']:.1%} of attempted objects; "
        f"ended in the wrong bin: {s['ended in the wrong bin, of attempted objects']:.1%}",
    ]
    if len(s["plans"]) > 1 or "pickplace" not in s["plans"]:
        plans = ", ".join(f"{p} {f:.1%} (full task solved in {ok:.1%} of them)" for p, (f, ok) in s["plans"].items())
        lines.append(f"- plans: {plans}")
    lines.append(f"- policy finished its script within the episode: {s['policy finished within the episode']:.1%}")
    if "steps to finish (mean / max)" in s:
        mean, mx = s["steps to finish (mean / max)"]
        lines.append(f"- steps to finish: mean {mean:.1f}, max {mx}")
    lines.append(f"- object draws: {s['object draws']}")
    per = ", ".join(f"{o} {r:.1%} (n={n})" for o, (r, n) in s["pick-and-place success by object"].items())
    lines.append(f"- pick-and-place success (placed in the intended bin; real grasps) by object: {per}")
    lines += [
        "",
        "| stage | episodes | grasped | grasp failed | placed in intended bin | in a bin | "
        "in its correct bin | wrong bin chosen |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, v in s.items():
        if k.startswith("stage"):
            gr = v["grasped (lifted off the table)"]
            lines.append(
                f"| {k} | {v['episodes']} | {gr:.1%} | {1 - gr:.1%} | {v['placed in the intended bin']:.1%} | "
                f"{v['ended in a bin']:.1%} | {v['ended in its correct bin']:.1%} | "
                f"{v['wrong bin chosen']:.1%} |"
            )
    return "\n".join(lines)


def first_frames(n: int = 8, size: int = 128) -> np.ndarray:
    """uint8 (2 * size, n / 2 * size, 3): the first side-camera frame of episodes 0..n-1 of wx-sorting."""
    spec = get_spec(TASKS[0])
    gen = make_generator(spec)
    frames = []
    for i in range(n):
        ep = gen.episode(i, episode_rng(spec.dataset.default_seed, i))
        frames.append(render_states(ep.arrays["states"][:1], ep.meta, size=size)[0])
    rows = [np.concatenate(frames[k : k + n // 2], axis=1) for k in (0, n // 2)]
    return np.concatenate(rows, axis=0)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--from-disk", action="store_true", help="read the generated datasets instead of regenerating")
    p.add_argument("--task", choices=TASKS, action="append", help="only this task's dataset (repeatable)")
    p.add_argument("--frames", metavar="PNG", help="write the first frames of 8 wx-sorting episodes to PNG and exit")
    args = p.parse_args(argv)
    if args.frames:
        import imageio.v3 as iio

        iio.imwrite(args.frames, first_frames(), optimize=True)
        return
    for task in args.task or TASKS:
        print(to_markdown(task, stats(episode_metas(task, args.episodes, args.from_disk))))
        print()


if __name__ == "__main__":
    main()
