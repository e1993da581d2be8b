"""What portable numerics cost in generation speed: the same episodes generated with each CPU's fastest
kernels (native) and with the pinned, CPU-independent ones (portable, ``d5rl.numerics``).

    python bench/portable_numerics.py                          # A1, standard kitchen, WidowX: 3 episodes each
    python bench/portable_numerics.py --task a1-walk-v0 --episodes 8 --repeats 3

Each measurement runs in a fresh process started with (portable) or without (native) the pinned
environment, generating the episodes in memory (no disk writes); the figure is the ratio of the
medians of the generation times (above 1: portable is slower). It also says whether the two made the
same bytes.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TASKS = ("a1-walk-v0", "kitchen-standard-mixed-state-v0", "wx-sorting-state-v0")
CHILD = """
import hashlib, json, sys, time
from d5rl.datasets.generation import episode_rng, make_generator
from d5rl import numerics
gen = make_generator(sys.argv[1])
h, steps = hashlib.sha256(), 0
t = time.perf_counter()
for i in range(int(sys.argv[2])):
    ep = gen.episode(i, episode_rng(0, i))
    steps += ep.num_transitions
    for k in sorted(ep.arrays):
        h.update(ep.arrays[k].tobytes())
print(json.dumps({"s": time.perf_counter() - t, "steps": steps, "digest": h.hexdigest(), "mode": numerics.current()}))
"""


def environments() -> dict[str, dict[str, str]]:
    from d5rl import numerics

    pinned = numerics.portable_env()
    native = {k: v for k, v in os.environ.items() if k not in pinned}
    native["PYTHONPATH"] = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {"native": native, "portable": {**native, **numerics.portable_env(native)}}


def measure(task: str, episodes: int, env: dict[str, str]) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, task, str(episodes)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", action="append", help=f"task(s) to generate (default: {', '.join(TASKS)})")
    ap.add_argument("--episodes", type=int, default=3, help="episodes per measurement (default 3)")
    ap.add_argument("--repeats", type=int, default=1, help="measurements per mode, alternating (default 1)")
    args = ap.parse_args()
    from d5rl import numerics

    if not numerics.supported():
        sys.exit("portable numerics are defined for x86-64 Linux with glibc only")
    envs = environments()
    print(f"machine: {numerics.machine()}; {args.episodes} episodes per run, median of {args.repeats}")
    print(f"{'task':34s} {'native s':>9s} {'portable s':>11s} {'ratio':>6s}  same bytes")
    for task in args.task or TASKS:
        runs: dict[str, list[dict]] = {"native": [], "portable": []}
        for _ in range(args.repeats):
            for mode, env in envs.items():
                r = measure(task, args.episodes, env)
                assert r["mode"] == mode, f"the {mode} process reports {r['mode']} numerics"
                runs[mode].append(r)
        t = {m: statistics.median(r["s"] for r in rs) for m, rs in runs.items()}
        same = runs["native"][0]["digest"] == runs["portable"][0]["digest"]
        print(
            f"{task:34s} {t['native']:9.2f} {t['portable']:11.2f} {t['portable'] / t['native']:6.2f}  "
            f"{'yes' if same else 'no'}",
            flush=True,
        )


if __name__ == "__main__":
    main()
