"""Reference returns for the A1 normalized scores, written to ``scores.json``.

    d5rl calibrate a1-walk-v0 [--episodes 20]

``random`` is the mean return of uniform random actions; ``expert`` is the mean
return of the best final policy (deterministic actions) on the task itself among the
task's data agents and the reference agent trained for it (``registration.SCORE_AGENTS``:
``run-1.25`` for walk and run, ``hiking`` for the course).  A normalized score of 1
therefore means "as good as the best agent we trained for this task", 0 "as good as
random actions".  Each agent's mean forward
speed over its episodes is recorded with its return (``d5rl info`` shows the expert's).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from d5rl.envs.a1.published import POLICY_DIR
from d5rl.envs.a1.registration import SCORE_AGENTS, SCORES_FILE
from d5rl.errors import D5RLError
from d5rl.production.a1.agents import describe
from d5rl.production.a1.policy import SnapshotPolicy, run_episodes
from d5rl.registry import get_spec, make_env


def evaluate(task_id: str, policy: SnapshotPolicy, episodes: int, seed: int, deterministic: bool = True) -> dict:
    """``policy`` on the task: per-episode returns, mean forward speeds, lengths, falls (:func:`run_episodes`)."""
    env = make_env(task_id)
    try:
        return run_episodes(env, policy, episodes, seed, deterministic)
    finally:
        env.close()


def calibrate(task_id: str, episodes: int = 20, seed: int = 0) -> dict:
    get_spec(task_id)
    random_return = np.mean(evaluate(task_id, SnapshotPolicy(None), episodes, seed, deterministic=False)["returns"])
    best_agent, best = None, -np.inf
    per_agent, per_agent_speed = {}, {}
    for agent in SCORE_AGENTS[task_id]:
        r = evaluate(task_id, SnapshotPolicy(POLICY_DIR / agent / "final.npz"), episodes, seed)
        ret = float(np.mean(r["returns"]))
        per_agent[agent] = round(ret, 3)
        per_agent_speed[agent] = round(float(np.mean(r["speeds"])), 3)
        if ret > best:
            best_agent, best = agent, ret
    return {
        "random": round(float(random_return), 3),
        "expert": round(best, 3),
        "expert_agent": best_agent,
        "expert_speed": per_agent_speed[best_agent],  # m/s, mean forward speed of its episodes
        "expert_trained": describe(best_agent),
        "per_agent": per_agent,
        "per_agent_speed": per_agent_speed,
        "source": f"d5rl calibrate {task_id} --episodes {episodes} --seed {seed}: mean return of uniform random "
        f"actions / of agent '{best_agent}' (final policy, deterministic)",
    }


def write_scores(task_id: str, result: dict, path: Path = SCORES_FILE) -> None:
    table = json.loads(path.read_text()) if path.exists() else {}
    table[task_id] = result
    path.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")


def add_calibrate_parser(subparsers) -> None:
    q = subparsers.add_parser("calibrate", help="measure an A1 task's random and expert reference returns")
    q.add_argument("task", choices=sorted(SCORE_AGENTS))
    q.add_argument("--episodes", type=int, default=20)
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--dry-run", action="store_true", help="print, do not write scores.json")

    def run(args) -> int:
        if args.episodes < 1:
            raise D5RLError(f"--episodes must be at least 1, got {args.episodes}", "the references use 20")
        result = calibrate(args.task, args.episodes, args.seed)
        print(json.dumps(result, indent=1))
        if not args.dry_run:
            write_scores(args.task, result)
            print(f"wrote {SCORES_FILE}")
        return 0

    q.set_defaults(func=run)
