"""The training loop: offline training, optional online fine-tuning, evaluation,
logging and checkpoints that resume exactly.

A run lives in one directory::

    run_dir/config.json       resolved agent + training config (written before training)
    run_dir/metrics.jsonl     one row per log / evaluation step (also metrics.csv, tb/ if TensorBoard)
    run_dir/checkpoint/       agent, optimizer, RNG states, replay buffer, step (atomic, checksummed;
                              the previous one is kept: see d5rl/training/checkpoint.py)
    run_dir/summary.json      final evaluation
    run_dir/videos/           evaluation videos (``save_video=True``)

Calling :func:`train` again on the same directory resumes from the checkpoint
and continues bit for bit as if never interrupted (offline checkpoints fall on
update boundaries, online ones on episode boundaries).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any, Iterable, Mapping

import jax
import numpy as np

from d5rl.agents import get_agent
from d5rl.agents.config import Bound, Config, ConfigError
from d5rl.agents.networks import is_pixel_obs
from d5rl.errors import D5RLError
from d5rl.training.checkpoint import Checkpoint, load_checkpoint, restore_agent, save_checkpoint
from d5rl.training.envs import load_task_dataset, make_task_env
from d5rl.training.evaluation import evaluate
from d5rl.training.logger import Logger
from d5rl.training.replay import ReplayBuffer

BATCH_KEYS = ("observations", "actions", "rewards", "masks", "next_observations")


class NonFiniteLossError(D5RLError, FloatingPointError):
    """A loss or metric became NaN or infinite."""


class RunDirError(D5RLError):
    """A run directory that holds a different run."""


def get_train_config() -> Config:
    return Config(
        eval_interval=10_000,  # updates (offline) / env steps (online) between evaluations (D5RL kitchen: 10k)
        eval_episodes=10,  # episodes per evaluation (D5RL: 50 kitchen, 100 A1 at the end, 20 WidowX)
        final_eval_episodes=None,  # episodes of the evaluation at the end (None = eval_episodes)
        eval_envs=5,  # environments stepped in lockstep during evaluation (batched inference)
        eval_processes=False,  # one process per evaluation env (gymnasium AsyncVectorEnv)
        log_interval=1_000,  # steps between metric rows
        checkpoint_interval=50_000,  # steps between checkpoints (online: at the next episode end)
        updates_per_call=8,  # offline updates per jit call via lax.scan (state agents; pixel agents use 1)
        frame_stack=None,  # stacked frames for pixel observations (None = 3 for pixels, 1 for states)
        offline_ratio=None,  # share of online-phase batches from the offline data (None = agent's, else 0.5)
        start_steps=None,  # random-action env steps before online updates (None = agent's start_steps, else 0)
        buffer_capacity=None,  # online replay capacity (None = online_steps; pixels: at most 20k, ~3 GB at 64²×2 cams)
        dataset_episodes=None,  # train on the first N dataset episodes (None = all)
        save_video=False,  # record the first episode of every evaluation
        tensorboard=True,  # also write TensorBoard events if tensorboardX / torch is installed
        progress=True,  # tqdm progress bar with updates/s
    )


# What each training setting may be (checked before any work; see get_train_config for meanings).
TRAIN_BOUNDS = {
    "eval_interval": Bound(int, ge=0), "eval_episodes": Bound(int, ge=1),
    "final_eval_episodes": Bound(int, ge=1, optional=True), "eval_envs": Bound(int, ge=1),
    "log_interval": Bound(int, ge=1), "checkpoint_interval": Bound(int, ge=1), "updates_per_call": Bound(int, ge=1),
    "frame_stack": Bound(int, ge=1, optional=True), "offline_ratio": Bound(float, ge=0, le=1, optional=True),
    "start_steps": Bound(int, ge=0, optional=True), "buffer_capacity": Bound(int, ge=1, optional=True),
    "dataset_episodes": Bound(int, ge=1, optional=True),
}


def check_run(offline_steps, online_steps, seed) -> None:
    """One-line errors for step counts and seeds that cannot make a run."""
    for name, v in (("--offline-steps", offline_steps), ("--online-steps", online_steps), ("--seed", seed)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ConfigError(f"{name} must be a non-negative integer, got {v!r}", f"pass e.g. {name} 0")
    if offline_steps == 0 and online_steps == 0:
        raise ConfigError("nothing to train: --offline-steps and --online-steps are both 0",
                          "pass --offline-steps N (and/or --online-steps N)")


def split_overrides(overrides, agent_config: Config, train_config: Config) -> tuple[Config, Config]:
    """Apply ``key=value`` overrides to whichever config owns the key (training keys first)."""
    if not overrides:
        return agent_config, train_config
    items = overrides.items() if isinstance(overrides, Mapping) else [tuple(o.split("=", 1)) for o in overrides]
    agent_items, train_items = [], []
    for item in items:
        if len(item) != 2:
            raise ConfigError(f"override {item[0]!r} is not key=value", "write e.g. --set batch_size=128")
        k, v = item[0].strip(), item[1]
        target = train_items if k in train_config else agent_items if k in agent_config else None
        if target is None:
            raise ConfigError(f"unknown config key {k!r}",
                              f"agent keys: {sorted(agent_config)}; training keys: {sorted(train_config)}")
        target.append((k, v))

    def apply(cfg, pairs):
        if not pairs:
            return cfg
        if isinstance(overrides, Mapping):
            return cfg.override(dict(pairs))
        return cfg.override([f"{k}={v}" for k, v in pairs])

    return apply(agent_config, agent_items), apply(train_config, train_items)


def observation_stats(ds, eps: float = 1e-3) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per-dimension mean and std + ``eps`` of a state dataset's observations (TD3+BC's normalization)."""
    obs = np.asarray(ds.observations, dtype=np.float64)
    return tuple(float(x) for x in obs.mean(0)), tuple(float(x) for x in obs.std(0) + eps)


def default_run_dir(algo: str, task_id: str, seed: int) -> Path:
    return Path("runs") / task_id / algo / f"seed{seed}"


# --- batches ---------------------------------------------------------------------------------------------
def _as_batch(b: dict, keys) -> dict:
    out = {}
    for k in keys:
        v = b[k]
        out[k] = v if isinstance(v, dict) else np.asarray(v, np.float32 if k in ("rewards", "masks", "mc_returns") else None)
    return out


def _mix(offline: dict, online: dict, utd: int) -> dict:
    """Concatenate so that each of the ``utd`` consecutive minibatches holds its share of both parts."""
    def join(x, y):
        xs = x.reshape((utd, -1) + x.shape[1:])
        ys = y.reshape((utd, -1) + y.shape[1:])
        z = np.concatenate([xs, ys], axis=1)
        return z.reshape((-1,) + z.shape[2:])

    return jax.tree_util.tree_map(join, offline, online)


def _check_finite(metrics: dict, step: int) -> None:
    bad = [k for k, v in metrics.items() if not math.isfinite(v)]
    if bad:
        raise NonFiniteLossError(
            f"non-finite values at step {step}: {', '.join(f'{k}={metrics[k]}' for k in bad)}",
            "lower the learning rates (--set actor_lr=... critic_lr=...) or check the dataset for NaN rewards; "
            "the run can resume from its last checkpoint",
        )


class _Progress:
    def __init__(self, total: int, initial: int, enabled: bool):
        self.bar = None
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=initial, unit="step", dynamic_ncols=True, smoothing=0.05, mininterval=1.0)

    def update(self, n: int, **postfix) -> None:
        if self.bar is not None:
            self.bar.update(n)
            if postfix:
                self.bar.set_postfix(postfix, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _crossed(prev: int, now: int, interval: int) -> bool:
    return interval > 0 and now // interval > prev // interval


# --- the loop ----------------------------------------------------------------------------------------------
def train(
    algo: str,
    task_id: str,
    offline_steps: int = 0,
    online_steps: int = 0,
    seed: int = 0,
    overrides: Iterable[str] | Mapping[str, Any] | None = None,
    run_dir: str | Path | None = None,
    *,
    dataset=None,
    tuned: bool = True,
    _stop_at: int | None = None,
) -> dict[str, Any]:
    """Train ``algo`` on ``task_id``; returns the final evaluation (also in ``summary.json``).

    ``offline_steps`` gradient updates on the task's dataset, then ``online_steps``
    environment steps with one update each, mixing ``offline_ratio`` of every batch
    from the dataset.  RLPD runs its online phase from a freshly initialised agent
    (as in the D5RL paper); every other agent fine-tunes.  ``overrides`` are
    ``key=value`` strings (or a dict) for the agent's or the loop's config
    (:func:`get_train_config`), layered over the task's settings (:mod:`d5rl.settings`; ``tuned=False``
    leaves them out).  ``dataset`` replaces the task's dataset (tests).
    """
    from d5rl.settings import resolve

    check_run(offline_steps, online_steps, seed)
    run = resolve(algo, task_id, overrides, offline_steps=offline_steps, online_steps=online_steps, tuned=tuned)
    agent_cls, _ = get_agent(run.algo)
    agent_cfg, cfg, algo = run.agent, run.train, run.algo
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir(algo, task_id, seed)

    ds = dataset if dataset is not None else load_task_dataset(
        task_id, **({"episodes": cfg.dataset_episodes} if cfg.dataset_episodes else {}))
    run_dir.mkdir(parents=True, exist_ok=True)
    probe = ds.sample(1, np.random.default_rng(0))
    pixels = is_pixel_obs(probe["observations"])
    if agent_cfg.get("normalize_observations") and not pixels and agent_cfg.obs_mean is None:
        mean, std = observation_stats(ds)
        agent_cfg = agent_cfg.replace(obs_mean=mean, obs_std=std)
    frame_stack = int(cfg.frame_stack)
    needs_mc = algo == "calql"
    gamma = float(agent_cfg.get("discount", 0.99))
    batch_keys = BATCH_KEYS + (("mc_returns",) if needs_mc else ())
    utd = int(agent_cfg.get("utd_ratio", 1))
    per_update = int(agent_cfg.batch_size) * utd

    def sample_offline(n: int, rng: np.random.Generator) -> dict:
        b = ds.sample(n, rng, frame_stack=frame_stack, **({"mc_gamma": gamma} if needs_mc else {}))
        return _as_batch(b, batch_keys)

    example = sample_offline(1, np.random.default_rng(0))
    agent = agent_cls.create(seed, example["observations"], example["actions"], agent_cfg)
    resolved = {
        "algo": algo, "task_id": task_id, "seed": seed, "offline_steps": offline_steps, "online_steps": online_steps,
        "agent": agent.get_config().to_dict(), "train": {**cfg.to_dict(), "frame_stack": frame_stack},
    }
    config_path = run_dir / "config.json"
    resume = load_checkpoint(run_dir)
    if config_path.exists() and resume is not None:
        old = json.loads(config_path.read_text())
        same = {k: old.get(k) for k in ("algo", "task_id", "seed", "agent")} == \
               {k: resolved[k] for k in ("algo", "task_id", "seed", "agent")}
        if not same:
            raise RunDirError(f"{run_dir} holds a run with a different algorithm, task, seed or agent config",
                              "pick another --run-dir, or delete that directory to start over")
    config_path.write_text(json.dumps(resolved, indent=2) + "\n")

    logger = Logger(run_dir, tensorboard=cfg.tensorboard)
    rng = np.random.default_rng([seed, 1])
    act_key = jax.random.PRNGKey(seed + 7919)
    step, online_done, episode = 0, 0, 0
    buffer = None
    offline_ratio = cfg.offline_ratio if cfg.offline_ratio is not None else agent_cfg.get("offline_ratio", 0.5)
    start_steps = cfg.start_steps if cfg.start_steps is not None else agent_cfg.get("start_steps", 0)
    fresh_online = algo == "rlpd" and offline_steps > 0
    capacity = int(cfg.buffer_capacity or (min(max(online_steps, 1), 20_000) if pixels else max(online_steps, 1)))

    if resume is not None:
        state, buf_state = resume.state, resume.buffer
        if state["online_started"] and fresh_online:
            agent = agent_cls.create(seed + 1, example["observations"], example["actions"], agent_cfg)
        agent = restore_agent(agent, resume)
        rng.bit_generator.state = state["rng"]
        step, online_done, episode = state["step"], state["online_done"], state["episode"]
        logger.truncate_after(step)
        if buf_state is not None:
            env_probe = make_task_env(task_id, frame_stack)
            ex_obs = env_probe.reset(seed=0)[0]
            buffer = ReplayBuffer(ex_obs, example["actions"].shape[-1], capacity)
            buffer.load_state_dict(buf_state)
            env_probe.close()

    def checkpoint():
        state = {"rng": rng.bit_generator.state, "step": step, "online_done": online_done, "episode": episode,
                 "metric_sums": dict(acc), "metric_count": acc_n,
                 "online_started": step > offline_steps or (online_done > 0)}
        save_checkpoint(run_dir, Checkpoint(agent.to_bytes(), state,
                                            buffer.state_dict() if buffer is not None else None))

    def run_eval(at_step: int, episodes: int) -> dict:
        video = run_dir / "videos" / f"step{at_step:09d}.mp4" if cfg.save_video else None
        res = evaluate(agent, task_id, episodes, seed=10_000 * (seed + 1), num_envs=cfg.eval_envs,
                       frame_stack=frame_stack, processes=cfg.eval_processes, video_path=video)
        row = {f"eval/{task_id}/{k}": res[k] for k in ("return", "return_std", "length", "success", "score")
               if k in res}
        logger.log(at_step, row)
        return res

    total = offline_steps + online_steps
    bar = _Progress(total, step, cfg.progress)
    acc: dict[str, float] = dict(resume.state.get("metric_sums", {})) if resume is not None else {}
    acc_n = int(resume.state.get("metric_count", 0)) if resume is not None else 0
    t_window, n_window = time.perf_counter(), 0

    def record(metrics, n_updates: int):
        nonlocal acc_n, n_window
        host = {k: float(v) for k, v in jax.device_get(metrics).items()}
        _check_finite(host, step)
        for k, v in host.items():
            acc[k] = acc.get(k, 0.0) + v * n_updates
        acc_n += n_updates
        n_window += n_updates

    def maybe_log(prev: int):
        nonlocal acc, acc_n, t_window, n_window
        if _crossed(prev, step, cfg.log_interval) and acc_n:
            dt = time.perf_counter() - t_window
            row = {k: v / acc_n for k, v in acc.items()}
            row["time/updates_per_s"] = n_window / max(dt, 1e-9)
            logger.log(step, row)
            bar.update(0, ups=f"{row['time/updates_per_s']:.1f}")
            acc, acc_n, t_window, n_window = {}, 0, time.perf_counter(), 0

    final = None
    try:
        # ---------------- offline ----------------
        k = 1 if pixels else max(1, int(cfg.updates_per_call))
        while step < offline_steps:
            n = min(k - step % k, offline_steps - step)
            if n == 1:
                agent, metrics = agent.update_donated(sample_offline(per_update, rng))
            else:
                batch = sample_offline(n * per_update, rng)
                batch = jax.tree_util.tree_map(lambda x: x.reshape((n, per_update) + x.shape[1:]), batch)
                agent, metrics = agent.update_many(batch)
            prev, step = step, step + n
            record(metrics, n)
            bar.update(n)
            maybe_log(prev)
            if _crossed(prev, step, cfg.eval_interval) and step < total:
                run_eval(step, cfg.eval_episodes)
            if _crossed(prev, step, cfg.checkpoint_interval) or step == offline_steps:
                checkpoint()
            if _stop_at is not None and step >= _stop_at:
                raise KeyboardInterrupt(f"stopped at step {step} (test hook)")

        # ---------------- online ----------------
        if online_steps > 0 and online_done < online_steps:
            if fresh_online and online_done == 0:
                agent = agent_cls.create(seed + 1, example["observations"], example["actions"], agent_cfg)
            env = make_task_env(task_id, frame_stack)
            obs, _ = env.reset(seed=seed * 1_000_003 + episode)
            if buffer is None:
                buffer = ReplayBuffer(obs, example["actions"].shape[-1], capacity)
            n_off = utd * int(round(int(agent_cfg.batch_size) * offline_ratio))
            ep_idx, ep_rew, ckpt_due = [], [], False
            while online_done < online_steps:
                if online_done < start_steps:
                    action = rng.uniform(-1, 1, example["actions"].shape[-1]).astype(np.float32)
                else:
                    action = np.asarray(agent.sample_actions(obs, seed=jax.random.fold_in(act_key, online_done)))
                next_obs, reward, term, trunc, info = env.step(action)
                ep_idx.append(buffer.insert(obs, action, reward, 1.0 - float(term), next_obs))
                ep_rew.append(float(reward))
                obs = next_obs
                online_done += 1
                prev, step = step, step + 1
                if online_done > start_steps and len(buffer) > 0:
                    on = _as_batch(buffer.sample(per_update - n_off, rng), batch_keys)
                    batch = _mix(sample_offline(n_off, rng), on, utd) if n_off else on
                    agent, metrics = agent.update_donated(batch)
                    record(metrics, 1)
                bar.update(1)
                maybe_log(prev)
                ckpt_due |= _crossed(prev, step, cfg.checkpoint_interval)
                if _crossed(prev, step, cfg.eval_interval) and step < total:
                    run_eval(step, cfg.eval_episodes)
                if term or trunc:
                    if needs_mc:
                        buffer.set_mc_returns(ep_idx, ep_rew, gamma)
                    logger.log(step, {"train/episode_return": sum(ep_rew), "train/episode_length": len(ep_rew)})
                    ep_idx, ep_rew = [], []
                    episode += 1
                    if ckpt_due or online_done == online_steps:
                        checkpoint()
                        ckpt_due = False
                    obs, _ = env.reset(seed=seed * 1_000_003 + episode)
                if _stop_at is not None and step >= _stop_at:
                    raise KeyboardInterrupt(f"stopped at step {step} (test hook)")
            env.close()
            checkpoint()

        final = run_eval(step, cfg.final_eval_episodes or cfg.eval_episodes)
        summary = {"step": step, "run_dir": str(run_dir), **{k: v for k, v in final.items() if k != "returns"}}
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return {**summary, "agent": agent}
    finally:
        bar.close()
        logger.close()


def load_run(run_dir: str | Path):
    """``(agent, resolved_config)`` from a run directory's config and latest checkpoint."""
    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    if not config_path.exists():
        raise RunDirError(f"{run_dir} has no config.json", "pass the directory a `d5rl train` run wrote")
    resolved = json.loads(config_path.read_text())
    ckpt = load_checkpoint(run_dir)
    if ckpt is None:
        raise RunDirError(f"{run_dir} has no checkpoint yet", "wait for the first checkpoint or train longer")
    agent_cls, agent_config_fn = get_agent(resolved["algo"])
    cfg = Config(resolved["agent"])
    env = make_task_env(resolved["task_id"], resolved["train"]["frame_stack"])
    obs, _ = env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    env.close()
    agent = agent_cls.create(resolved["seed"], obs, action, cfg)
    return restore_agent(agent, ckpt), resolved
