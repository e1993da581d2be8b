"""Is a cell's A1 walk/run score one lucky rollout?  Evaluate its checkpoint from perturbed starts.

On `a1-walk-v1` / `a1-run-v1` every episode starts from the same pose (the release's `SimpleRun`), so a
deterministic agent's evaluation episodes are one rollout.  This evaluates a cell's final checkpoint as its
final evaluation did (same evaluation seed, five episodes at a time) and then again with each episode's
start perturbed: every joint angle moved by a uniform draw in ±NOISE rad (seeded by the episode's reset
seed), placed as the env places its start (`A1EnvV1._place_robot`: the trunk at the release's first
contact-free height on its 1 cm grid).  NOISE 0 must reproduce the
cell's published score (the control column).

    python docs/experiments/a1-updates/perturbed_starts.py CELL_DIR [CELL_DIR ...] [--noise 0.01] [--episodes 20]

Needs the cells' checkpoints (they stay on the machine that trained them: train the cell with the grid's
`d5rl bench` command first).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

from d5rl.envs.a1.model import NOMINAL_POSE
from d5rl.training.envs import episode_scorer, make_task_env
from d5rl.training.evaluation import evaluate
from d5rl.training.loop import load_run
from d5rl.training.parts import evaluation_seed


class PerturbedStart(gym.Wrapper):
    """Moves every joint of the A1's start pose by U(-noise, noise) rad, drawn from the reset seed."""

    def __init__(self, env: gym.Env, noise: float):
        super().__init__(env)
        self.noise = noise

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self.noise > 0:
            a1 = self.env.unwrapped
            rng = np.random.default_rng([seed, 2718])
            a1._place_robot(*a1.task.start_xy(), NOMINAL_POSE + rng.uniform(-self.noise, self.noise, 12))
            obs = a1._obs()
        return obs, info


def evaluate_cell(cell: Path, noise: float, episodes: int) -> dict:
    agent, resolved = load_run(cell)
    task, train = resolved["task_id"], resolved["train"]
    if task not in ("a1-walk-v1", "a1-run-v1"):
        raise SystemExit(f"{cell}: a cell of a1-walk-v1 or a1-run-v1, not {task} (hiking starts vary already)")
    seed = evaluation_seed(resolved["seed"])
    scorer = episode_scorer(task)

    def run(level: float) -> dict:
        out = evaluate(
            agent,
            task,
            episodes,
            seed,
            num_envs=train["eval_envs"],
            env_fn=lambda: PerturbedStart(make_task_env(task, train["frame_stack"]), level),
        )
        # evaluate() scores only unwrapped task envs; score the returns here the same way
        ended = out["stats"]["ended_early"]
        scores = [scorer(r, {}) for r in out["returns"]]
        return {
            "score": float(np.mean(scores)),
            "score_std": float(np.std(scores)),
            "ended_early": ended,
            "speed": out["stats"]["forward_speed"],
            "scores": scores,
        }

    summary = json.loads((cell / "summary.json").read_text())
    return {
        "cell": str(cell),
        "task": task,
        "algo": resolved["algo"],
        "seed": resolved["seed"],
        "published": summary["score"],
        "control": run(0.0),
        "perturbed": run(noise),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cells", nargs="+", type=Path)
    parser.add_argument("--noise", type=float, default=0.01, help="joint perturbation in rad (default 0.01)")
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    print("| cell | published | noise 0 | perturbed: score ± std (episodes) | ended early | speed m/s |")
    print("|---|---:|---:|---|---:|---:|")
    for cell in args.cells:
        r = evaluate_cell(cell, args.noise, args.episodes)
        c, p = r["control"], r["perturbed"]
        name = f"{r['task']} {r['algo']} seed {r['seed']}"
        print(
            f"| {name} | {r['published']:.3f} | {c['score']:.3f} | {p['score']:.3f} ± {p['score_std']:.3f} "
            f"({args.episodes}) | {p['ended_early']:.2f} | {p['speed']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
