"""Statistics of the generated A1 datasets for docs/datacards/a1.md.

    python -m d5rl.envs.a1.datacard_stats          # reads the generated datasets (d5rl generate first)

Prints Markdown: size, per-agent composition, return distributions under each
task's relabelled reward, and a histogram of the forward speed in the data.
"""

from __future__ import annotations

import argparse

import numpy as np

from d5rl.datasets.loading import load_dataset
from d5rl.registry import get_spec


def episode_returns(ds) -> np.ndarray:
    return np.add.reduceat(np.asarray(ds.rewards, np.float64), ds.episode_starts)


def speed_histogram(speeds: np.ndarray, lo=-0.2, hi=1.4, width=0.1) -> str:
    edges = np.arange(lo, hi + 1e-9, width)
    counts, _ = np.histogram(np.clip(speeds, lo, hi - 1e-9), edges)
    frac = counts / max(counts.sum(), 1)
    rows = ["| forward speed (m/s) | share of steps | |", "|---|---:|---|"]
    for a, b, f in zip(edges[:-1], edges[1:], frac):
        rows.append(f"| {a:+.1f} … {b:+.1f} | {100 * f:5.1f}% | {'█' * int(round(60 * f))} |")
    return "\n".join(rows)


def describe(task_ids: tuple[str, ...]) -> str:
    ds = load_dataset(task_ids[0], generate=False, progress=False)
    meta = ds.episode_meta
    out = [f"### `{ds.metadata['dataset']}` (used by {', '.join(f'`{t}`' for t in task_ids)})", ""]
    out.append(f"- episodes: {ds.num_episodes}, transitions: {ds.num_transitions}, "
               f"terminated by a fall: {100 * np.mean([bool(ds.terminals[s + n - 1]) for s, n in zip(ds.episode_starts, ds.episode_lengths)]):.1f}% of episodes")
    agents = sorted({m["agent"] for m in meta})
    for a in agents:
        sel = [i for i, m in enumerate(meta) if m["agent"] == a]
        rand = sum(m["snapshot"] == "random" for m in (meta[i] for i in sel))
        steps = int(ds.episode_lengths[sel].sum())
        out.append(f"- agent `{a}`: {len(sel)} episodes ({rand} before learning, uniform random actions), {steps} steps")
    out.append("")
    out.append("| task | return mean ± std | 10% / 50% / 90% quantile | normalized (mean) |")
    out.append("|---|---|---|---|")
    for tid in task_ids:
        d = load_dataset(tid, generate=False, progress=False)
        r = episode_returns(d)
        s = get_spec(tid).score
        norm = f"{np.mean((r - s.random) / (s.expert - s.random)):.3f}" if s else "n/a"
        q = np.quantile(r, [0.1, 0.5, 0.9])
        out.append(f"| `{tid}` | {r.mean():.1f} ± {r.std():.1f} | {q[0]:.1f} / {q[1]:.1f} / {q[2]:.1f} | {norm} |")
    out.append("")
    out.append(speed_histogram(np.asarray(ds.arrays["infos/forward_speed"])))
    return "\n".join(out)


def main(argv=None) -> None:
    argparse.ArgumentParser(description=__doc__).parse_args(argv)
    print(describe(("a1-walk-v0", "a1-run-v0")))
    print()
    print(describe(("a1-hiking-v0",)))


if __name__ == "__main__":
    main()
