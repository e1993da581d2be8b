"""Statistics of the randomized-kitchen datasets and of the skilled operator, for the data card.

    nice -n 5 python -m d5rl.production.kitchen.randomized.datacard sample --episodes 160 [--modes play]  # first N
    nice -n 5 python -m d5rl.production.kitchen.randomized.datacard grasps --seeds 12    # per object model
    nice -n 5 python -m d5rl.production.kitchen.randomized.datacard corners --seeds 8    # pose-range corners
    nice -n 5 python -m d5rl.production.kitchen.randomized.datacard full                 # generated datasets
    python -m d5rl.production.kitchen.randomized.datacard frames --out docs/img/kitchen-randomized-domains.png

Grasp and corner success: the skilled operator does one subtask alone in a random domain with the
model / pose fixed, and succeeds if the subtask's object reaches its goal within 250 steps.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools

import numpy as np

from d5rl.datasets import format as fmt
from d5rl.datasets import generation
from d5rl.datasets.generation import episode_rng
from d5rl.datasets.loading import load_dataset
from d5rl.envs.kitchen.randomized import domain as dm
from d5rl.envs.kitchen.randomized import objects
from d5rl.envs.kitchen.randomized.task import RandomizedKitchenEnv
from d5rl.envs.kitchen.subtasks import SUBTASK_NAMES
from d5rl.errors import DatasetNotFoundError
from d5rl.production.kitchen.demonstrator import Demonstrator
from d5rl.production.kitchen.randomized.data import MODES, SKILLED, RandomizedKitchenGenerator
from d5rl.registry import get_spec

PAPER = {"demos": 4.0, "play": 3.62, "suboptimal": 3.55}
DATASETS = {
    "demos": "kitchen-randomized-demos-v0",
    "play": "kitchen-randomized-mixed-v0",
    "suboptimal": "kitchen-randomized-suboptimal-v0",
}


def operator_solves(subtask: str, replace: dict, seed: int, steps: int = 250, before: tuple = ()) -> bool:
    """Whether the skilled operator gets ``subtask``'s object to its goal within ``steps`` (after doing
    the ``before`` subtasks), in a random domain with the fields ``replace`` set."""
    rng = np.random.default_rng([7, seed])
    domain = dataclasses.replace(dm.Domain.sample(rng), **replace)
    env = _env()
    env.reset(seed=seed, options={"domain": domain})
    policy = Demonstrator(env, [*before, subtask], rng, style=SKILLED.style(rng), transit_first=True)
    column = SUBTASK_NAMES.index(subtask)
    for _ in range(steps + 120 * len(before)):
        env.step(policy.act())
        if env.completed()[column]:
            return True
    return False


_ENV = []


def _env():
    if not _ENV:
        _ENV.append(RandomizedKitchenEnv(obs_mode="state"))
    return _ENV[0]


def grasp_table(seeds: int) -> list[str]:
    rows = [
        "| object | model | handle (radius, half-length) m | mass kg | skilled operator, subtask alone |",
        "|---|---|---|---|---|",
    ]
    for k, m in enumerate(objects.KETTLES):  # from each start site (the far one is the harder reach)
        ok = [
            sum(operator_solves("kettle", {"kettle": k, "kettle_site": site}, s) for s in range(seeds))
            for site in range(len(dm.KETTLE_SITES))
        ]
        per_site = ", ".join(f"site {site}: {n} / {seeds}" for site, n in enumerate(ok))
        rows.append(f"| kettle | {k}: {m.name} | bar across the top {m.handle_size} | {m.mass} | {per_site} |")
    for k, m in enumerate(objects.MICROWAVES):
        ok = sum(operator_solves("microwave", {"microwave": k}, s) for s in range(seeds))
        rows.append(
            f"| microwave | {k}: {m.name} | vertical bar {m.handle_size} | door {m.door_mass} | {ok} / {seeds} |"
        )
    return rows


def corners() -> dict[str, list[tuple[str, dict]]]:
    """The corners of each pose range, as Domain fields."""
    out = {"kettle": [], "microwave": []}
    for site, x, y, yaw in itertools.product(
        range(len(dm.KETTLE_SITES)), dm.KETTLE_X, dm.KETTLE_Y, (-dm.KETTLE_YAW, dm.KETTLE_YAW)
    ):
        label = f"site {site}, dx {x:+.2f}, dy {y:+.2f}, yaw {np.degrees(yaw):+.0f} deg"
        out["kettle"].append((label, {"kettle_site": site, "kettle_offset": (x, y), "kettle_yaw": yaw}))
    for x, y, yaw in itertools.product(dm.MICROWAVE_X, dm.MICROWAVE_Y, dm.MICROWAVE_YAW):
        label = f"dx {x:+.2f}, dy {y:+.2f}, yaw {np.degrees(yaw):.0f} deg"
        out["microwave"].append((label, {"microwave_pose": (x, y, yaw)}))
    return out


def corner_table(seeds: int) -> list[str]:
    rows = ["| subtask | corner | skilled operator, subtask alone (random models) |", "|---|---|---|"]
    for subtask, cases in corners().items():
        for label, replace in cases:
            ok = sum(operator_solves(subtask, replace, s) for s in range(seeds))
            rows.append(f"| {subtask} | {label} | {ok} / {seeds} |")
    return rows


def sample_stats(mode: str, episodes: int, seed: int = 0) -> dict:
    """Statistics of the dataset's first ``episodes`` episodes, generated without frames (the same
    episodes, byte for byte, as ``d5rl generate``'s: one generator per episode index and seed)."""
    g = RandomizedKitchenGenerator(mode=mode)
    return _stats([g.episode(i, episode_rng(seed, i)).meta for i in range(episodes)])


def _stats(metas: list[dict]) -> dict:
    solved = np.array([m["num_solved"] for m in metas])
    asked = np.array([len(m["subtasks"]) for m in metas])
    return {
        "episodes": len(metas),
        "objects_per_episode": float(solved.mean()),
        "objects_std": float(solved.std()),
        "subtasks_asked": float(asked.mean()),
        "all_solved": float(np.mean([set(m["subtasks"]) <= set(m["solved"]) for m in metas])),
        "operators": {o: sum(m["operator"] == o for m in metas) for o in sorted({m["operator"] for m in metas})},
    }


def stats_table(stats: dict[str, dict]) -> list[str]:
    rows = [
        "| dataset | episodes | objects/episode (ours) | paper | difference | subtasks asked | all asked solved "
        "| operators |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, s in stats.items():
        mode = name.split()[0]
        rows.append(
            f"| {name} | {s['episodes']} | {s['objects_per_episode']:.2f} ± {s['objects_std']:.2f} | "
            f"{PAPER[mode]} | {s['objects_per_episode'] - PAPER[mode]:+.2f} | {s['subtasks_asked']:.2f} | "
            f"{100 * s['all_solved']:.1f}% | {s['operators']} |"
        )
    return rows


def full_stats() -> dict[str, dict]:
    """Statistics of the generated datasets; of a dataset still being generated, of its finished
    shards (a prefix of its episodes; each shard checked against its checksums)."""
    out = {}
    for mode, task in DATASETS.items():
        try:
            out[mode] = _stats(load_dataset(task, generate=False, render=False, progress=False).episode_meta)
        except DatasetNotFoundError:
            dspec = generation.dataset_spec(get_spec(task))
            shards = sorted((generation.dataset_root(dspec, dspec.default_seed) / "shards").glob("shard-*"))
            metas = []
            for d in shards:  # contiguous finished shards from the first
                rec = fmt.read_shard_record(d)
                if rec["episodes"][0] != len(metas) or fmt.check_shard(d, rec):
                    break
                metas += rec["episode_meta"]
            if metas:
                out[f"{mode} (first {len(metas)} of {dspec.num_episodes}, generation running)"] = _stats(metas)
    return out


def domain_grid(path: str, n: int = 8, seed: int = 0, size: int = 128) -> None:
    """A PNG grid: ``n`` random domains (rows) seen by the left, right and wrist cameras at reset."""
    import imageio.v3 as iio

    env = RandomizedKitchenEnv(image_size=size)
    rows = []
    for i in range(n):
        obs, _ = env.reset(seed=seed + i)
        rows.append(np.concatenate([obs[f"pixels/{c}"] for c in ("left", "right", "wrist")], axis=1))
    grid = np.concatenate([np.concatenate(rows[: n // 2], axis=0), np.concatenate(rows[n // 2 :], axis=0)], axis=1)
    iio.imwrite(path, grid, extension=".png", optimize=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("sample", "grasps", "corners", "full", "frames"))
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--modes", nargs="+", choices=sorted(MODES), default=sorted(MODES), help="sample: which datasets")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--out", default="docs/img/kitchen-randomized-domains.png")
    a = p.parse_args()
    if a.what == "sample":
        rows = stats_table({f"{mode} (first {a.episodes})": sample_stats(mode, a.episodes) for mode in a.modes})
    elif a.what == "grasps":
        rows = grasp_table(a.seeds)
    elif a.what == "corners":
        rows = corner_table(a.seeds)
    elif a.what == "full":
        rows = stats_table(full_stats())
    else:
        domain_grid(a.out)
        rows = [f"wrote {a.out}"]
    print("\n".join(rows), flush=True)


if __name__ == "__main__":
    main()
