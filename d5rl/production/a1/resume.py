"""A1 agent training across machines (checkpoints without replay buffers, and their refill) and
shipping the finished agents (:func:`publish`).

A full checkpoint (``WORK_DIR/<agents>/checkpoint``) holds the replay buffers, ~100 MB per agent:
too large to commit.  :func:`export` writes each one without its buffer, plus the finished
agents' learners, to :data:`SAVED_DIR` (committed with the snapshots in ``SAVED_DIR/policies``);
a trainer with no checkpoint of its own resumes from there and :func:`refill_buffer` replays
every segment's snapshot for the steps it acted, as the dataset generator does.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from d5rl.envs.a1.published import POLICY_DIR
from d5rl.errors import D5RLError
from d5rl.production.a1.agents import AGENTS, training_reward
from d5rl.production.a1.policy import SnapshotPolicy
from d5rl.training.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from d5rl.training.rundir import RunDir

WORK_DIR = Path("runs") / "a1-experts"  # full checkpoints (with replay buffers): this machine only
SAVED_DIR = Path("experiments") / "a1-agents"  # committed: policies/, checkpoints/<agents>/, learners/


def record(buf: dict, i: int, pos: int, obs, action, reward: float, next_obs, terminated: bool) -> None:
    """Write agent ``i``'s transition at ``buf[key][i, pos]`` (the trainer's replay-buffer layout)."""
    buf["observations"][i, pos] = obs
    buf["actions"][i, pos] = action
    buf["rewards"][i, pos] = reward
    buf["next_observations"][i, pos] = next_obs
    buf["masks"][i, pos] = 0.0 if terminated else 1.0


def refill_buffer(buf: dict, t: int, segments, names, envs, policy_dir: Path, seed: int) -> None:
    """Fill ``buf[key][i, :t]`` for agent ``names[i]`` by replaying each segment's acting policy
    (its snapshot; uniform actions before learning) for the steps it acted, with the training reward."""
    for i, (name, env, segs) in enumerate(zip(names, envs, segments)):
        spec, pos = AGENTS[name], 0
        for j, seg in enumerate(segs):
            rng = np.random.default_rng([seed, i, j])
            policy = SnapshotPolicy(None if seg.snapshot is None else Path(policy_dir) / name / seg.snapshot)
            obs, _ = env.reset(seed=int(rng.integers(2**31)))
            length = 0
            for _ in range(seg.steps):
                action = policy(obs, rng)
                nxt, _, term, _, info = env.step(action)
                record(buf, i, pos, obs, action, training_reward(spec, info), nxt, term)
                pos, length, obs = pos + 1, length + 1, nxt
                if term or length >= spec.episode_steps:
                    (obs, _), length = env.reset(seed=int(rng.integers(2**31))), 0
        if pos != t:
            raise ValueError(f"{name}: the segments' steps add up to {pos}, the checkpoint is at step {t}")


def publish(agents, trained_dir: Path = SAVED_DIR / "policies", dest: Path = POLICY_DIR) -> None:
    """Ship finished agents: a data agent's snapshots, final policy and log (the dataset generator
    replays them); a reference agent's final policy and log only.  Replaces what ``dest`` held."""
    for name in agents:
        src = Path(trained_dir) / name
        if not (src / "final.npz").exists():
            raise D5RLError(
                f"{name} has not finished training ({src / 'final.npz'} is missing)",
                "train it to its --steps first (python -m d5rl.production.a1.experts train ...)",
            )
    for name in agents:
        src, out = Path(trained_dir) / name, Path(dest) / name
        files = sorted(src.glob("*.npz")) if AGENTS[name].role == "data" else [src / "final.npz"]
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        for f in [*files, src / "log.json"]:
            shutil.copyfile(f, out / f.name)
        print(f"{src} -> {out} ({len(files)} policies)")


def export(work_root: Path = WORK_DIR, saved_root: Path = SAVED_DIR) -> None:
    """Copy each training's latest checkpoint under ``work_root`` without its replay buffer, and the
    finished agents' learners, to ``saved_root``."""
    work_root, saved_root = Path(work_root), Path(saved_root)
    for run in sorted(p.parent for p in work_root.glob("*/checkpoint")):
        ckpt = load_checkpoint(run)
        dest = saved_root / "checkpoints" / "+".join(ckpt.state["agents"])
        save_checkpoint(dest, Checkpoint(ckpt.agent, ckpt.state, None))
        shutil.rmtree(RunDir(dest).previous_checkpoint, ignore_errors=True)
        print(f"{run} (step {ckpt.state['t']}) -> {dest}")
    for f in sorted((work_root / "learners").glob("*.msgpack")):
        (saved_root / "learners").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(f, saved_root / "learners" / f.name)
        print(f"{f} -> {saved_root / 'learners' / f.name}")
