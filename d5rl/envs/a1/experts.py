"""Train the data-collecting A1 agents (SAC with a LayerNorm critic pair, RLPD-style, UTD > 1).

    python -m d5rl.envs.a1.experts --agent speed-0.5 --steps 40000

writes ``policies/<agent>/snapshot-XX.npz`` along training plus ``policies/<agent>/log.json``
(for every snapshot: the env steps and episodes it collected, their mean return and
speed).  The dataset generator replays these snapshots for the same number of
episodes, which reproduces the agent's replay buffer from first exploration to
expert without re-running RL on every user's machine.  Training itself needs the
``train`` extra and takes hours on 2 CPU cores; the committed snapshots are its output.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from d5rl.envs.a1.policy import save_actor

POLICY_DIR = Path(__file__).with_name("policies")
EPISODE_STEPS = 400
AGENTS = {
    # name: (target speed m/s, command)
    "speed-0.5": (0.5, "forward"),
    "speed-0.8": (0.8, "forward"),
    "speed-1.0": (1.0, "forward"),
    "heading": (0.75, "heading"),
}


def make_env(agent: str):
    from d5rl.envs.a1.task import A1Env

    speed, command = AGENTS[agent]
    return A1Env(target_speed=speed, command=command)


def train(agent: str, steps: int, seed: int, snapshot_every: int, start_steps: int, utd: int,
          out: Path = POLICY_DIR, log_every: int = 2000, max_minutes: float | None = None) -> dict:
    import jax
    from d5rl.agents import rlpd

    env = make_env(agent)
    config = rlpd.get_config().replace(
        num_qs=2, num_min_qs=2, utd_ratio=utd, batch_size=256, start_steps=start_steps, hidden_dims=(256, 256),
    )
    obs, _ = env.reset(seed=seed)
    learner = rlpd.RLPDAgent.create(seed, obs[None], np.zeros((1, 12), np.float32), config)
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed + 1)
    n_obs = obs.shape[0]
    buf = {
        "observations": np.zeros((steps, n_obs), np.float32),
        "next_observations": np.zeros((steps, n_obs), np.float32),
        "actions": np.zeros((steps, 12), np.float32),
        "rewards": np.zeros(steps, np.float32),
        "masks": np.zeros(steps, np.float32),
    }
    out_dir = out / agent
    out_dir.mkdir(parents=True, exist_ok=True)
    segments = [{"snapshot": None, "start_step": 0, "episodes": 0, "steps": 0, "returns": [], "speeds": []}]
    ep_ret, ep_speed, ep_len = 0.0, [], 0
    t0 = time.time()
    for t in range(steps):
        if t == start_steps or (t > start_steps and (t - start_steps) % snapshot_every == 0):
            _write_log(out_dir, agent, seed, steps, utd, start_steps, snapshot_every, t0, config, segments)
            if max_minutes is not None and time.time() - t0 > 60 * max_minutes:
                print(f"[{agent}] stopping at step {t}: wall-clock budget of {max_minutes} min used", flush=True)
                break
            name = f"snapshot-{len(segments):02d}.npz"
            save_actor(learner.actor.params, out_dir / name)
            segments.append({"snapshot": name, "start_step": t, "episodes": 0, "steps": 0, "returns": [],
                             "speeds": []})
        if t < start_steps:
            action = rng.uniform(-1, 1, 12).astype(np.float32)
        else:
            key, k = jax.random.split(key)
            action = np.asarray(learner.sample_actions(obs, seed=k))
        nxt, r, term, _, info = env.step(action)
        ep_len += 1
        trunc = ep_len >= EPISODE_STEPS
        buf["observations"][t], buf["actions"][t], buf["rewards"][t] = obs, action, r
        buf["next_observations"][t], buf["masks"][t] = nxt, 0.0 if term else 1.0
        ep_ret += r
        ep_speed.append(info["forward_speed"])
        obs = nxt
        if term or trunc:
            seg = segments[-1]
            seg["episodes"] += 1
            seg["returns"].append(ep_ret)
            seg["speeds"].append(float(np.mean(ep_speed)))
            obs, _ = env.reset(seed=int(rng.integers(2**31)))
            ep_ret, ep_speed, ep_len = 0.0, [], 0
        segments[-1]["steps"] += 1
        if t >= start_steps:
            idx = rng.integers(0, t + 1, utd * 256)
            learner, metrics = learner.update({k: v[idx] for k, v in buf.items()})
        if (t + 1) % log_every == 0:
            seg = segments[-1]
            recent = seg["returns"][-5:] or [float("nan")]
            print(f"[{agent}] step {t + 1}/{steps}  {time.time() - t0:.0f}s  return(last5) {np.mean(recent):.1f}  "
                  f"speed {np.mean(seg['speeds'][-5:] or [np.nan]):.2f}", flush=True)
    save_actor(learner.actor.params, out_dir / "final.npz")
    return _write_log(out_dir, agent, seed, steps, utd, start_steps, snapshot_every, t0, config, segments)


def _write_log(out_dir, agent, seed, steps, utd, start_steps, snapshot_every, t0, config, segments) -> dict:
    log = {
        "agent": agent, "target_speed": AGENTS[agent][0], "command": AGENTS[agent][1], "seed": seed,
        "steps": steps, "utd": utd, "start_steps": start_steps, "snapshot_every": snapshot_every,
        "train_seconds": round(time.time() - t0), "config": config.to_dict(),
        "segments": [
            {**{k: s[k] for k in ("snapshot", "start_step", "episodes", "steps")},
             "mean_return": float(np.mean(s["returns"])) if s["returns"] else None,
             "mean_speed": float(np.mean(s["speeds"])) if s["speeds"] else None}
            for s in segments
        ],
    }
    (out_dir / "log.json").write_text(json.dumps(log, indent=1, default=str) + "\n")
    return log


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agent", choices=sorted(AGENTS), required=True)
    ap.add_argument("--steps", type=int, default=40000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--snapshot-every", type=int, default=4000)
    ap.add_argument("--start-steps", type=int, default=2000)
    ap.add_argument("--utd", type=int, default=4)
    ap.add_argument("--out", type=Path, default=POLICY_DIR)
    ap.add_argument("--log-every", type=int, default=2000)
    ap.add_argument("--max-minutes", type=float, help="stop at the first snapshot after this much wall-clock time")
    args = ap.parse_args(argv)
    train(args.agent, args.steps, args.seed, args.snapshot_every, args.start_steps, args.utd, args.out, args.log_every, args.max_minutes)


if __name__ == "__main__":
    main()
