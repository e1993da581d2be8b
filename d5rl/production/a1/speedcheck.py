"""The speed bar of the A1 agents: how fast each final policy really moves, and whether it falls.

    python -m d5rl.production.a1.experts check [--agents speed-0.5 ...] [--episodes 10]

For every agent, its final policy (``policies/<agent>/final.npz``) runs full episodes on the
environment it was trained on, with deterministic actions and with the policy's own sampling
noise (as when it collected data).  Prints a Markdown table: mean forward speed over whole
episodes (from the first step, so the start from rest counts), its error against the target,
falls, and whether the agent meets the bar: mean speed within 5% of the target and no falls.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d5rl.envs.a1.published import POLICY_DIR
from d5rl.production.a1.agents import AGENTS, make_env
from d5rl.production.a1.policy import SnapshotPolicy, run_episodes

BAR = 0.05  # relative speed error allowed


def rollouts(agent: str, episodes: int, seed: int, deterministic: bool, policy_dir: Path = POLICY_DIR) -> dict:
    """Per-episode mean forward speed, length and whether it fell, for an agent's final policy on the env
    it was trained on (:func:`d5rl.production.a1.policy.run_episodes`)."""
    env = make_env(agent)
    try:
        return run_episodes(
            env,
            SnapshotPolicy(Path(policy_dir) / agent / "final.npz"),
            episodes,
            seed,
            deterministic,
            max_steps=AGENTS[agent].episode_steps,
        )
    finally:
        env.close()


def check(agent: str, episodes: int = 10, seed: int = 0, policy_dir: Path = POLICY_DIR) -> list[dict]:
    target = AGENTS[agent].target_speed
    rows = []
    for mode in ("deterministic", "stochastic"):
        r = rollouts(agent, episodes, seed, mode == "deterministic", policy_dir)
        mean = float(np.mean(r["speeds"]))
        err = (mean - target) / target
        rows.append(
            {
                "agent": agent,
                "mode": mode,
                "target": target,
                "mean_speed": mean,
                "speed_std": float(np.std(r["speeds"])),
                "error": err,
                "falls": int(sum(r["falls"])),
                "episodes": episodes,
                "meets_bar": bool(abs(err) <= BAR and not any(r["falls"])),
            }
        )
    return rows


def main(agents, episodes: int = 10, seed: int = 0, policy_dir: Path = POLICY_DIR) -> list[dict]:
    rows = [row for a in agents for row in check(a, episodes, seed, policy_dir)]
    print(
        f"final policies in {policy_dir}, {episodes} episodes per agent and mode, seeds {seed * 100_003}..; "
        "speed = mean forward speed over whole episodes (m/s)\n"
    )
    print("| agent | policy | target | mean speed ± std over episodes | error | falls | within 5%, no falls |")
    print("|---|---|---:|---|---:|---:|:---:|")
    for r in rows:
        print(
            f"| `{r['agent']}` | {r['mode']} | {r['target']:.2f} | {r['mean_speed']:.3f} ± {r['speed_std']:.3f} "
            f"| {100 * r['error']:+.1f}% | {r['falls']}/{r['episodes']} | {'yes' if r['meets_bar'] else 'no'} |"
        )
    return rows
