"""Where a trained critic puts the policy's own actions against the data's, on dataset states.

For a run's checkpoint and a sample of its task's transitions, the lower of the critic's heads at
(s, a) for three kinds of action: the dataset's ``a``, the policy's evaluation action ``π(s)`` and
uniform random actions; the mean gap Q(s, a_data) − Q(s, π(s)); and how far the policy's actions
lie from the data's (mean absolute difference per action dimension).

    python -m d5rl.runner.qprobe RUN_DIR [RUN_DIR ...] [--samples 2048] [--seed 0]

Why it helps: a conservative critic that values the policy's actions a gap ``g`` below the data's
carries that gap into every backup (its target takes π's action at s'), so with mean reward ``r̄``
its values head for about (r̄ − γ·g) / (1 − γ): below zero once γ·g > r̄, even where no reward is
negative. A negative gap (the policy's actions valued above the data's) is a less conservative critic.
For agents with a Q critic of ``(observations, actions)`` (CQL, CalQL, IQL, TD3+BC, RLPD, ReBRAC,
IDQL, FQL) from state observations.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from d5rl.errors import D5RLError
from d5rl.training.envs import load_task_dataset


def q_of(agent, observations, actions) -> np.ndarray:
    """The lower of the critic heads' Q(s, a), shape ``(batch,)``."""
    critic = getattr(agent, "critic", None)
    if critic is None:
        raise D5RLError(f"{type(agent).__name__} has no Q critic to probe", "probe a CQL, CalQL, IQL, ... run")
    q = np.asarray(critic.apply_fn({"params": critic.params}, observations, actions))
    return q.min(axis=0) if q.ndim == 2 else q


def q_probe(agent, batch: dict, rng: np.random.Generator) -> dict:
    """The probe's numbers for ``agent`` on ``batch`` (observations, actions, rewards); uniform actions
    in [-1, 1] drawn from ``rng``."""
    obs, act = batch["observations"], np.asarray(batch["actions"], np.float32)
    if isinstance(obs, dict) or np.ndim(obs) != 2:
        raise D5RLError(
            f"the Q probe needs flat state observations, got shape {np.shape(obs)}",
            "probe a run on a state task (kitchen and WidowX: their -state twins)",
        )
    import jax  # JAX (the train extra): loaded by the commands that need it

    policy = np.asarray(agent.eval_actions(obs, seed=jax.random.PRNGKey(0)), np.float32)  # diffusion, flow: seeded
    uniform = rng.uniform(-1.0, 1.0, act.shape).astype(np.float32)
    q_data, q_policy, q_uniform = (q_of(agent, obs, a) for a in (act, policy, uniform))
    return {
        "samples": len(act),
        "reward_mean": float(np.mean(batch["rewards"])),
        "q_data": float(q_data.mean()),
        "q_policy": float(q_policy.mean()),
        "q_uniform": float(q_uniform.mean()),
        "gap_data_policy": float(np.mean(q_data - q_policy)),
        "policy_action_distance": float(np.abs(policy - act).mean()),
    }


def probe_run(run_dir: str | Path, samples: int = 2048, seed: int = 0) -> dict:
    """:func:`q_probe` of a run directory's latest checkpoint on ``samples`` transitions of its task."""
    from d5rl.training.loop import load_run  # JAX (the train extra): loaded by the commands that need it

    if not 1 <= samples <= 1_000_000:
        raise D5RLError(f"--samples {samples} is not between 1 and 1,000,000", "pass e.g. --samples 2048")
    agent, cfg = load_run(run_dir)
    rng = np.random.default_rng(seed)
    batch = load_task_dataset(cfg["task_id"]).sample(samples, rng)
    return {"run": str(run_dir), "task": cfg["task_id"], "algo": cfg["algo"], **q_probe(agent, batch, rng)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m d5rl.runner.qprobe", description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", help="run directories (`d5rl train` or a grid's cells) with a checkpoint")
    p.add_argument("--samples", type=int, default=2048, help="dataset transitions to probe on")
    p.add_argument("--seed", type=int, default=0, help="seed of the transitions and the uniform actions")
    args = p.parse_args(argv)
    try:
        results = [probe_run(run, args.samples, args.seed) for run in args.runs]
    except D5RLError as e:
        print(f"error: {e}", file=sys.stderr)  # D5RLError reads "message (hint: ...)"
        return 2
    print("| run | mean reward | Q(s, a_data) | Q(s, π(s)) | Q(s, uniform) | gap data − π | abs(π(s) − a_data) |")
    print("|---|---|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['run']} | {r['reward_mean']:.3f} | {r['q_data']:.1f} | {r['q_policy']:.1f} | {r['q_uniform']:.1f} "
            f"| {r['gap_data_policy']:.2f} | {r['policy_action_distance']:.3f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
