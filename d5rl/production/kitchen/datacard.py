"""Statistics for the standard kitchen data card, next to the paper's numbers.

    python -m d5rl.production.kitchen.datacard [--episodes N] [--subtask-seeds 30] [--combo-seeds 4]
    python -m d5rl.production.kitchen.datacard --compare-human [--episodes N]

Loads (generating if needed) the ``kitchen-standard`` dataset, computes its size, episode
lengths, returns under both tasks' rewards and objects per episode, and measures the
scripted demonstrator's success rates (each subtask alone; every combination).  Prints
Markdown tables for ``docs/datacards/kitchen-standard.md``.  ``--compare-human`` instead puts the
scripted data next to the imported human data (``d5rl import-kitchen-human``): lengths, subtasks per
episode, the orders they are done in, action statistics.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from d5rl.datasets.generation import full_size
from d5rl.datasets.loading import load_dataset
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.production.kitchen.data import COMBINATIONS
from d5rl.production.kitchen.demonstrator import Demonstrator
from d5rl.production.kitchen.human import completion_order
from d5rl.registry import get_spec
from d5rl.rollout import STOP, rollout
from d5rl.rollout import Episode as RolloutEpisode

PAPER = {"episodes": 563, "transitions": 128_569, "mean_return": 261.12, "objects": 3.98, "combinations": 22}


def dataset_stats(episodes: int | None = None, workers: int | None = None) -> dict:
    ds = load_dataset("kitchen-standard-mixed-v0", episodes=episodes, workers=workers, render=False)
    done = np.asarray(ds.arrays["infos/completed"])
    ep = ds.transition_episode
    out = {
        "episodes": ds.num_episodes,
        "transitions": ds.num_transitions,
        "length_mean": float(ds.episode_lengths.mean()),
        "length_min": int(ds.episode_lengths.min()),
        "length_max": int(ds.episode_lengths.max()),
        "combinations": len({m["combination"] for m in ds.episode_meta}),
    }
    own = np.zeros(ds.num_episodes)
    own_return = np.zeros(ds.num_episodes)
    for i, meta in enumerate(ds.episode_meta):
        cols = [SUBTASK_NAMES.index(t) for t in meta["subtasks"]]
        rows = done[ep == i][:, cols]
        own[i] = rows.any(axis=0).sum()
        own_return[i] = rows.sum()
    out["objects_mean"] = float(own.mean())
    out["all_four"] = float((own == 4).mean())
    out["return_own_mean"] = float(own_return.mean())
    for name, tasks in (("mixed", MIXED), ("partial", PARTIAL)):
        cols = [SUBTASK_NAMES.index(t) for t in tasks]
        r = done[:, cols].sum(axis=1)
        out[f"return_{name}_mean"] = float(np.bincount(ep, weights=r, minlength=ds.num_episodes).mean())
        per_ep = np.array([done[ep == i][:, cols].any(axis=0).sum() for i in range(ds.num_episodes)])
        out[f"max_{name}_subtasks_in_an_episode"] = int(per_ep.max())
    out["subtask_frequency"] = {
        s: float(
            np.mean(
                [
                    done[ep == i][:, SUBTASK_NAMES.index(s)].any()
                    for i in range(ds.num_episodes)
                    if s in ds.episode_meta[i]["subtasks"]
                ]
            )
        )
        for s in SUBTASK_NAMES
    }
    assert len(COMBINATIONS) == 22
    return out


def comparison_stats(task: str, episodes: int | None = None, workers: int | None = None) -> dict:
    """What the scripted and the human data can be compared on, from what both store: episode lengths,
    ``infos/completed`` (which subtasks, in which order: by the step each first reaches its goal) and
    the actions."""
    from collections import Counter

    ds = load_dataset(task, episodes=episodes, workers=workers, render=False, progress=False)
    done = np.asarray(ds.arrays["infos/completed"])
    actions = np.asarray(ds.arrays["actions"], np.float64)
    bounds = list(zip(ds.episode_starts, ds.episode_starts + ds.episode_lengths))
    orders = [tuple(completion_order(done[a:b])) for a, b in bounds]
    counts = np.array([len(o) for o in orders])
    # consecutive actions within an episode (not across its boundary)
    inside = np.ones(len(actions), bool)
    inside[np.asarray(ds.episode_starts)] = False
    first = Counter(o[0] if o else "none" for o in orders)
    n = ds.num_episodes
    return {
        "episodes": n,
        "transitions": ds.num_transitions,
        "length_mean": float(ds.episode_lengths.mean()),
        "length_min": int(ds.episode_lengths.min()),
        "length_max": int(ds.episode_lengths.max()),
        "subtasks_mean": float(counts.mean()),
        "subtasks_hist": {k: int((counts == k).sum()) for k in range(8) if (counts == k).any()},
        "orders": len(set(orders)),
        "top_orders": [(list(o), c) for o, c in Counter(orders).most_common(3)],
        "first_subtask": {k: c / n for k, c in first.most_common()},
        "action_abs_mean": float(np.abs(actions).mean()),
        "action_std_mean": float(actions.std(axis=0).mean()),
        "action_saturated": float((np.abs(actions) >= 0.99).mean()),
        "action_change_mean": float(np.abs(np.diff(actions, axis=0))[inside[1:]].mean()) if inside[1:].any() else 0.0,
    }


def print_comparison(scripted: dict, human: dict | None) -> None:
    """The side-by-side Markdown table (``-`` where the human data are not imported)."""

    def col(s: dict | None, f) -> str:
        return "-" if s is None else f(s)

    rows = [
        ("episodes", lambda s: f"{s['episodes']}"),
        ("transitions", lambda s: f"{s['transitions']:,}"),
        ("episode length mean (min-max)", lambda s: f"{s['length_mean']:.1f} ({s['length_min']}-{s['length_max']})"),
        ("subtasks done per episode, mean", lambda s: f"{s['subtasks_mean']:.2f}"),
        (
            "episodes by number of subtasks done (subtasks: episodes)",
            lambda s: " / ".join(f"{k}: {v}" for k, v in s["subtasks_hist"].items()),
        ),
        ("distinct orders of completion", lambda s: f"{s['orders']}"),
        (
            "commonest orders (episodes)",
            lambda s: "; ".join(f"{' > '.join(o) or 'none'} ({c})" for o, c in s["top_orders"]),
        ),
        (
            "first subtask done (share of episodes)",
            lambda s: ", ".join(f"{k} {100 * v:.0f}%" for k, v in s["first_subtask"].items()),
        ),
        ("mean abs action", lambda s: f"{s['action_abs_mean']:.3f}"),
        ("action std (mean over the 9 dims)", lambda s: f"{s['action_std_mean']:.3f}"),
        ("actions at the bounds (abs >= 0.99)", lambda s: f"{100 * s['action_saturated']:.1f}%"),
        ("mean abs change between consecutive actions", lambda s: f"{s['action_change_mean']:.3f}"),
    ]
    print("\n| statistic | scripted (`kitchen-standard`) | human (`kitchen-standard-human`) |\n|---|---|---|")
    for name, f in rows:
        print(f"| {name} | {col(scripted, f)} | {col(human, f)} |")


def demonstrator_episode(env: KitchenEnv, subtasks, seed: int, max_steps: int = 280) -> RolloutEpisode:
    """The demonstrator doing ``subtasks`` in ``env`` (its episode from ``seed``) through the rollout loop,
    until the step that finishes its script (that step is taken) or ``max_steps``."""
    rng = np.random.default_rng(seed)
    made = []  # the demonstrator, made after the reset: it reads the scene

    def act(observations, live, steps):
        policy = made[0]
        return [STOP if policy.finished else policy.act()]

    (episode,) = rollout(
        [env],
        act,
        [int(rng.integers(2**31))],
        max_steps=max_steps,
        on_reset=lambda *_: made.append(Demonstrator(env, subtasks, rng)),
    )
    return episode


def demonstrator_rates(subtask_seeds: int, combo_seeds: int) -> dict:
    def run(seq, seeds):
        env = KitchenEnv(obs_mode="state", tasks=tuple(seq))
        episodes = [demonstrator_episode(env, seq, seed) for seed in seeds]
        return np.array([e.info["solved"].copy() for e in episodes]), np.array([e.length for e in episodes])

    single = {}
    for s in SUBTASK_NAMES:
        r, lengths = run([s], range(10_000, 10_000 + subtask_seeds))
        single[s] = (float(r.mean()), float(lengths.mean()))
    combos = []
    for i, c in enumerate(COMBINATIONS):
        r, lengths = run(list(c), range(20_000 + 100 * i, 20_000 + 100 * i + combo_seeds))
        combos.append((c, float(r.all(axis=1).mean()), r.mean(axis=0).tolist(), float(lengths.mean())))
    return {"single": single, "combos": combos}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=None, help="use only the first N episodes")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--subtask-seeds", type=int, default=30)
    p.add_argument("--combo-seeds", type=int, default=4)
    p.add_argument("--skip-dataset", action="store_true")
    p.add_argument("--skip-demonstrator", action="store_true")
    p.add_argument(
        "--compare-human",
        action="store_true",
        help="only the scripted data next to the imported human data (the first N episodes of each)",
    )
    args = p.parse_args()
    print(
        f"<!-- generated by `python -m d5rl.production.kitchen.datacard{' --compare-human' if args.compare_human else ''}"
        f"` on {platform.machine()}, {time.strftime('%Y-%m-%d', time.gmtime())} -->"
    )
    if args.compare_human:
        human_task = "kitchen-standard-mixed-state-human-v0"
        have = full_size(get_spec(human_task).dataset)
        human = (
            comparison_stats(human_task, None if args.episodes is None else min(args.episodes, have), args.workers)
            if have
            else None
        )
        if human is None:
            print(f"<!-- human data not imported: {get_spec(human_task).dataset.name} -->")
        print_comparison(comparison_stats("kitchen-standard-mixed-state-v0", args.episodes, args.workers), human)
        return
    if not args.skip_dataset:
        s = dataset_stats(args.episodes, args.workers)
        print("\n| statistic | d5rl (this dataset) | paper (RPL data re-rendered) |\n|---|---|---|")
        print(f"| episodes | {s['episodes']} | {PAPER['episodes']} |")
        print(f"| transitions | {s['transitions']:,} | {PAPER['transitions']:,} |")
        print(
            f"| episode length mean (min-max) | {s['length_mean']:.1f} ({s['length_min']}-{s['length_max']}) | "
            f"{PAPER['transitions'] / PAPER['episodes']:.1f} |"
        )
        print(f"| task combinations | {s['combinations']} | {PAPER['combinations']} |")
        print(f"| objects per episode (own 4 subtasks solved) | {s['objects_mean']:.2f} | {PAPER['objects']} |")
        print(f"| episodes solving all 4 | {100 * s['all_four']:.1f}% | - |")
        print(f"| mean return, own subtasks | {s['return_own_mean']:.1f} | {PAPER['mean_return']} |")
        print(f"| mean return, mixed-task relabel | {s['return_mixed_mean']:.1f} | - |")
        print(f"| mean return, partial-task relabel | {s['return_partial_mean']:.1f} | - |")
        print(f"| most partial-task subtasks in one episode | {s['max_partial_subtasks_in_an_episode']} | 3 |")
        print("\n| subtask | solved in episodes that attempt it |\n|---|---|")
        for k, v in s["subtask_frequency"].items():
            print(f"| {k} | {100 * v:.1f}% |")
    if not args.skip_demonstrator:
        d = demonstrator_rates(args.subtask_seeds, args.combo_seeds)
        print(f"\n| subtask alone ({args.subtask_seeds} seeds) | success | mean steps |\n|---|---|---|")
        for k, (rate, length) in d["single"].items():
            print(f"| {k} | {100 * rate:.0f}% | {length:.0f} |")
        print(
            f"\n| combination ({args.combo_seeds} seeds each) | all 4 | per subtask | mean steps |\n|---|---|---|---|"
        )
        for c, all4, per, length in d["combos"]:
            print(
                f"| {', '.join(c)} | {100 * all4:.0f}% | {' / '.join(f'{100 * x:.0f}' for x in per)} | {length:.0f} |"
            )
        all4 = np.mean([x[1] for x in d["combos"]])
        print(f"| **all combinations** | **{100 * all4:.0f}%** | | |")


if __name__ == "__main__":
    main()
