"""Statistics of the generated A1 datasets for docs/datacards/a1.md.

    python -m d5rl.production.a1.datacard_stats              # the v0 datasets (d5rl generate first)
    python -m d5rl.production.a1.datacard_stats --version 1  # the v1 datasets

Prints Markdown: size, per-agent composition (and how fast each agent's last snapshot walks in
the data), each agent's share of transitions per training stage (the snapshot that collected them),
return distributions under each task's relabelled reward, and histograms of the forward speed in
the data, overall and per agent.
"""

from __future__ import annotations

import argparse

import numpy as np

from d5rl.datasets.loading import load_dataset
from d5rl.registry import get_spec


def episode_returns(ds) -> np.ndarray:
    return np.add.reduceat(np.asarray(ds.rewards, np.float64), ds.episode_starts)


def speed_histogram(columns: dict[str, np.ndarray], lo=-0.2, hi=1.2, width=0.1) -> str:
    """Share of steps per forward-speed bin, one column per group of steps (the last bin is open)."""
    edges = np.arange(lo, hi + 1e-9, width)
    shares = {}
    for name, speeds in columns.items():
        counts, _ = np.histogram(np.clip(speeds, lo, hi - 1e-9), edges)
        shares[name] = counts / max(counts.sum(), 1)
    rows = ["| forward speed (m/s) | " + " | ".join(shares) + " |", "|---|" + "---:|" * len(shares)]
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        label = f"≥ {a:+.1f}" if i == len(edges) - 2 else f"{a:+.1f} … {b:+.1f}"
        rows.append(f"| {label} | " + " | ".join(f"{100 * f[i]:.1f}%" for f in shares.values()) + " |")
    return "\n".join(rows)


def stage_shares(ds) -> dict[str, list[tuple[int, str, int, float]]]:
    """Per agent, per training stage (segment) in its data: (segment, snapshot, first training step, share of
    the agent's transitions)."""
    meta = ds.episode_meta
    lengths = np.asarray(ds.episode_lengths)
    out = {}
    for agent in sorted({m["agent"] for m in meta}):
        stages: dict[int, list] = {}
        for m, n in zip(meta, lengths):
            if m["agent"] == agent:
                stages.setdefault(m["segment"], [m["snapshot"], m["training_step"], 0])[2] += int(n)
        total = sum(v[2] for v in stages.values())
        out[agent] = [(seg, snap, step, n / total) for seg, (snap, step, n) in sorted(stages.items())]
    return out


def stage_table(shares: dict[str, list[tuple[int, str, int, float]]]) -> str:
    """Markdown: one row per stage, one column per agent (share of its transitions, from training step)."""
    rows = ["| stage | " + " | ".join(f"`{a}`" for a in shares) + " |", "|---|" + "---:|" * len(shares)]
    for seg in sorted({s[0] for v in shares.values() for s in v}):
        cells = []
        for stages in shares.values():
            hit = [s for s in stages if s[0] == seg]
            cells.append(f"{100 * hit[0][3]:.1f}% (step {hit[0][2]:,})" if hit else "")
        name = next(s[1] for v in shares.values() for s in v if s[0] == seg)
        rows.append(f"| {seg}: {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def describe(task_ids: tuple) -> str:
    """The data card's statistics of the dataset the tasks (ids or specs) share."""
    ds = load_dataset(task_ids[0], generate=False, progress=False)
    meta = ds.episode_meta
    last_steps = np.asarray(ds.episode_starts) + np.asarray(ds.episode_lengths) - 1  # each episode's last transition
    names = [get_spec(t).id for t in task_ids]
    out = [f"### `{ds.metadata['dataset']}` (used by {', '.join(f'`{t}`' for t in names)})", ""]
    out.append(
        f"- episodes: {ds.num_episodes:,}, transitions: {ds.num_transitions:,}, "
        f"terminated by a fall: {100 * np.mean(np.asarray(ds.terminals[last_steps], bool)):.1f}% of episodes"
    )
    speed = np.asarray(ds.arrays["infos/forward_speed"])
    episode_speed = np.bincount(ds.transition_episode, weights=speed) / ds.episode_lengths
    agent = np.array([m["agent"] for m in meta])
    segment = np.array([m["segment"] for m in meta])
    columns = {"all steps": speed}
    for a in sorted(set(agent)):
        sel = np.flatnonzero(agent == a)
        rand = sum(meta[i]["snapshot"] == "random" for i in sel)
        steps = int(ds.episode_lengths[sel].sum())
        last = sel[segment[sel] == segment[sel].max()]
        out.append(
            f"- agent `{a}`: {len(sel)} episodes ({rand} before learning, uniform random actions), {steps:,} steps; "
            f"its last snapshot's {len(last)} episodes: mean forward speed {episode_speed[last].mean():.3f} m/s"
        )
        columns[f"`{a}`"] = speed[agent[ds.transition_episode] == a]
    out.append("")
    out.append("| task | return mean ± std | 10% / 50% / 90% quantile | normalized (mean) |")
    out.append("|---|---|---|---|")
    for tid in task_ids:
        d = load_dataset(tid, generate=False, progress=False)
        r = episode_returns(d)
        s = get_spec(tid).score
        tid = get_spec(tid).id
        norm = f"{np.mean((r - s.random) / (s.expert - s.random)):.3f}" if s else "n/a"
        q = np.quantile(r, [0.1, 0.5, 0.9])
        out.append(f"| `{tid}` | {r.mean():.1f} ± {r.std():.1f} | {q[0]:.1f} / {q[1]:.1f} / {q[2]:.1f} | {norm} |")
    out += [
        "",
        "Share of each agent's transitions per training stage (the snapshot that collected them; "
        "stage 0 is uniform random actions):",
        "",
        stage_table(stage_shares(ds)),
    ]
    out.append("")
    out.append(speed_histogram(columns))
    return "\n".join(out)


DATASETS = {0: (("a1-walk-v0", "a1-run-v0"), ("a1-hiking-v0",)), 1: (("a1-walk-v1", "a1-run-v1"), ("a1-hiking-v1",))}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", type=int, choices=sorted(DATASETS), default=0, help="the A1 tasks' version")
    args = p.parse_args(argv)
    print("\n\n".join(describe(tasks) for tasks in DATASETS[args.version]))


if __name__ == "__main__":
    main()
