"""The training loop: offline training, optional online fine-tuning, evaluation,
logging and checkpoints that resume exactly.

A run lives in one directory, whose files :class:`d5rl.training.rundir.RunDir` names, reads and writes: its
config, metrics, checkpoints (atomic and checksummed; the previous one is kept), final summary and videos.

:func:`train` reads top to bottom: resolve the settings, load the data, build (or restore) the
agent, run the offline phase, the online phase, the final evaluation.  What differs between
algorithms is asked of the agent (:class:`d5rl.agents.common.Agent`'s hooks).  Calling it again
on the same directory resumes from the checkpoint and continues bit for bit as if never
interrupted (offline checkpoints fall on update boundaries, online ones on episode boundaries).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import numpy as np

from d5rl.agents import get_agent
from d5rl.agents.config import Config
from d5rl.agents.encoders import is_pixel_obs
from d5rl.datasets.dataset import mc_tail
from d5rl.datasets.format import disk_full_error
from d5rl.datasets.generation import RESULT_IDENTITY_KEYS, result_identity
from d5rl.files import lock_holder, try_lock
from d5rl.progress import progress_bar
from d5rl.training.checkpoint import Checkpoint, check_state, load_checkpoint, restore_agent, save_checkpoint
from d5rl.training.config import RunSpec, check_run, final_eval_episodes
from d5rl.training.envs import load_task_dataset, make_task_env
from d5rl.training.logger import Logger
from d5rl.training.memory import check_memory
from d5rl.training.parts import Evaluator, Metrics, NonFiniteLossError, Prefetcher, RunState, Sampler, as_batch, crossed
from d5rl.training.replay import ReplayBuffer
from d5rl.training.rundir import RunDir, RunDirError

__all__ = ["NonFiniteLossError", "RunDirError", "load_run", "train"]


def default_run_dir(algo: str, task_id: str, seed: int) -> Path:
    return Path("runs") / task_id / algo / f"seed{seed}"


@dataclasses.dataclass
class Run:
    """What stays fixed during a run: where it writes, its settings and its parts."""

    task_id: str
    seed: int
    offline_steps: int
    online_steps: int
    run_dir: Path
    cfg: Config  # the loop's settings
    agent_cls: type
    agent_cfg: Config
    sampler: Sampler
    example: dict  # one batch row: observations and actions the agent is built from
    pixels: bool
    logger: Logger
    evaluate: Evaluator
    bar: Any

    def new_agent(self, seed: int):
        return self.agent_cls.create(seed, self.example["observations"], self.example["actions"], self.agent_cfg)

    def checkpoint(self, agent, state: RunState) -> None:
        save_checkpoint(
            self.run_dir,
            Checkpoint(
                agent.to_bytes(), state.to_json(), state.buffer.state_dict() if state.buffer is not None else None
            ),
        )

    def buffer(self, example_obs) -> ReplayBuffer:
        """The online replay buffer (capacity: the online steps; pixels at most 20k)."""
        capacity = self.cfg.buffer_capacity or (min(self.online_steps, 20_000) if self.pixels else self.online_steps)
        return ReplayBuffer(example_obs, self.example["actions"].shape[-1], max(int(capacity), 1))

    @property
    def fresh_online(self) -> bool:
        """The online phase starts from a new agent (RLPD after an explicit offline phase)."""
        return not self.agent_cls.offline_pretraining and self.offline_steps > 0


# --- the loop ----------------------------------------------------------------------------------------------
def train(spec: RunSpec, run_dir: str | Path | None = None, *, dataset=None) -> dict[str, Any]:
    """Train the run ``spec`` describes (:func:`d5rl.settings.resolve` makes it); returns the final evaluation
    (also in ``summary.json``).

    ``spec.offline_steps`` gradient updates on the task's dataset, then ``spec.online_steps`` environment steps
    with one update each, mixing the agent's share of offline data into every batch.  ``run_dir`` defaults to
    ``runs/TASK/ALGO/seedS``; ``dataset`` replaces the task's dataset (tests).
    """
    check_run(spec.offline_steps, spec.online_steps, spec.seed)
    task_id, cfg, agent_cls = spec.task_id, spec.train, get_agent(spec.algo)[0]
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir(spec.algo, task_id, spec.seed)
    data_kw = {"episodes": cfg.dataset_episodes} if cfg.dataset_episodes else {}
    if cfg.dataset_in_memory_gb is not None:
        data_kw["memory_limit_bytes"] = int(cfg.dataset_in_memory_gb * 2**30)
    ds = dataset if dataset is not None else load_task_dataset(task_id, **data_kw)
    agent_cfg = agent_cls.fit_config(spec.agent, ds)
    sampler = Sampler(ds, cfg.frame_stack, agent_cls.extra_batch_keys, agent_cfg.get("discount", 0.99))
    example = sampler.sample(1, np.random.default_rng(0))
    check_memory(agent_cfg, example)
    run_dir.mkdir(parents=True, exist_ok=True)
    with try_lock(RunDir(run_dir).train_lock) as locked:
        if not locked:  # two writers would delete each other's checkpoint temporaries and log every row twice
            holder = lock_holder(RunDir(run_dir).train_lock)
            raise RunDirError(
                f"another d5rl process{f' (pid {holder})' if holder else ''} is training into {run_dir}",
                "wait for it to finish (a second run resumes from its checkpoint), or pick another --run-dir",
            )
        try:
            return _train_locked(spec, agent_cls, agent_cfg, sampler, example, run_dir, ds)
        except OSError as e:
            full = disk_full_error(
                run_dir,
                e,
                "free some space or pick a --run-dir on a bigger disk, then run the "
                "same command again (it resumes from the last checkpoint)",
            )
            if full is not None:
                raise full from None
            raise


def _train_locked(spec: RunSpec, agent_cls, agent_cfg, sampler, example, run_dir: Path, ds) -> dict[str, Any]:
    cfg, offline_steps, online_steps = spec.train, spec.offline_steps, spec.online_steps
    resume = load_checkpoint(run_dir)
    _write_config(
        run_dir,
        spec,
        agent_cfg,
        resumed=resume is not None,
        dataset=_data_record(ds),
        agent_version=agent_cls.version,
    )
    logger = Logger(run_dir, tensorboard=cfg.tensorboard)
    run = Run(
        spec.task_id,
        spec.seed,
        offline_steps,
        online_steps,
        run_dir,
        cfg,
        agent_cls,
        agent_cfg,
        sampler,
        example,
        is_pixel_obs(example["observations"]),
        logger,
        Evaluator(spec.task_id, spec.seed, cfg.frame_stack, cfg, logger, RunDir(run_dir)),
        progress_bar(
            total=offline_steps + online_steps,
            unit="step",
            dynamic_ncols=True,
            smoothing=0.05,
            mininterval=1.0,
            disable=not cfg.progress,
        ),
    )
    agent, state = _start(run, resume)
    try:
        finished = _finished_summary(run_dir, state.step, offline_steps + online_steps)
        if finished is not None:  # ran to the end and evaluated: evaluating again would log a second final row
            return {**finished, "agent": agent}
        agent = offline_phase(run, agent, state)
        agent = online_phase(run, agent, state)
        final = run.evaluate(agent, state, final_eval_episodes(cfg))
        summary = {
            "step": state.step,
            "run_dir": str(run_dir),
            **final,  # with each episode's return, length and score: a published mean can be checked episode by episode
            "run_wall_s": round(state.elapsed(), 1),
            "resumed": resume is not None,
        }
        RunDir(run_dir).write_summary(summary)
        return {**summary, "agent": agent}
    finally:
        run.bar.close()
        logger.close()


def _finished_summary(run_dir: Path, step: int, total: int) -> dict | None:
    """The ``summary.json`` of a run that resumed at its last step after its final evaluation, else None."""
    if step < total:
        return None
    summary = RunDir(run_dir).read_summary()
    return summary if summary is not None and summary.get("step") == step else None


def _data_record(ds) -> dict | None:
    """The dataset a run trains on (its identity and the episodes used), for config.json; None for data
    that is not a generated d5rl dataset (in-memory test data)."""
    meta = getattr(ds, "metadata", {}) or {}
    if not all(k in meta for k in RESULT_IDENTITY_KEYS):
        return None
    source = {"source": meta["source"]} if "source" in meta else {}  # an imported dataset: which file
    return {**result_identity(meta), "episodes": int(ds.num_episodes), **source}


def _write_config(
    run_dir: Path,
    spec: RunSpec,
    agent_cfg: Config,
    resumed: bool,
    dataset: dict | None = None,
    agent_version: int = 1,
) -> None:
    """``config.json``: what this run is, including the dataset it trains on and the version of the agent's
    code (reports use both to tell results of older data or older agents apart); a resumed run must be the
    same run on the same data."""
    resolved = {
        **spec.to_json(),
        "agent": agent_cfg.to_dict(),
        "agent_version": agent_version,
        **({"dataset": dataset} if dataset is not None else {}),
    }
    files = RunDir(run_dir)
    if resumed and files.config.exists():
        old = files.read_config()
        keys = ("algo", "task_id", "seed", "agent")
        if {k: old.get(k) for k in keys} != {k: resolved[k] for k in keys} or old.get(
            "agent_version", 1
        ) != agent_version:
            raise RunDirError(
                f"{run_dir} holds a run with a different algorithm, task, seed, agent config or agent version",
                "pick another --run-dir, or delete that directory to start over",
            )
        if "dataset" in old and dataset is not None and old["dataset"] != dataset:
            raise RunDirError(
                f"{run_dir} holds a run trained on other data ({old['dataset']}); this one loads {dataset}",
                "pick another --run-dir, or delete that directory to start over",
            )
    files.write_config(resolved)


def _start(run: Run, resume: Checkpoint | None) -> tuple[Any, RunState]:
    """A new agent and state, or those of the checkpoint."""
    agent = run.new_agent(run.seed)
    if resume is None:  # a fresh start: rows an earlier, killed attempt logged here are stale
        run.logger.truncate_after(-1)
        return agent, RunState(np.random.default_rng([run.seed, 1]))
    buffer = None
    if resume.buffer is not None:
        env = make_task_env(run.task_id, run.cfg.frame_stack)
        buffer = run.buffer(env.reset(seed=0)[0])
        buffer.load_state_dict(resume.buffer)
        env.close()
    state = RunState.from_json(check_state(resume.state, Path(resume.path or ".") / "state.json"), buffer)
    if state.online_started and run.fresh_online:
        agent = run.new_agent(run.seed + 1)
    run.logger.truncate_after(state.step)
    run.bar.update(state.step)
    return restore_agent(agent, resume), state


def offline_phase(run: Run, agent, state: RunState):
    """``offline_steps`` updates on dataset batches (state agents: several per jit call; pixel agents: one,
    on batches whose frames are gathered ahead in background threads)."""
    n_batch = agent.samples_per_update()
    if run.pixels and state.step < run.offline_steps:
        with Prefetcher(run.sampler, n_batch, state.rng) as batches:
            return _offline_updates(run, agent, state, n_batch, 1, batches.next)
    k = max(1, int(run.cfg.updates_per_call))
    return _offline_updates(run, agent, state, n_batch, k, lambda: run.sampler.sample(n_batch, state.rng))


def _offline_updates(run: Run, agent, state: RunState, n_batch: int, k: int, next_batch):
    """The offline loop: ``k`` updates of ``n_batch`` samples per jit call (``update_many`` on stacked
    batches), else one per ``next_batch()``."""
    cfg, metrics = run.cfg, Metrics(state, run.logger, run.cfg.log_interval, run.bar)
    total = run.offline_steps + run.online_steps
    while state.step < run.offline_steps:
        n = min(k - state.step % k, run.offline_steps - state.step)
        if n == 1:
            agent, info = agent.update_donated(next_batch())
        else:
            agent, info = agent.update_many(run.sampler.sample_stacked(n, n_batch, state.rng))
        prev, state.step = state.step, state.step + n
        metrics.record(info, n)
        run.bar.update(n)
        metrics.maybe_log(prev)
        if crossed(prev, state.step, cfg.eval_interval) and state.step < total:
            run.evaluate(agent, state, cfg.eval_episodes)
        if crossed(prev, state.step, cfg.checkpoint_interval) or state.step == run.offline_steps:
            run.checkpoint(agent, state)
    return agent


def online_phase(run: Run, agent, state: RunState):
    """``online_steps`` environment steps, one update each (after the agent's random start steps),
    every batch mixing offline data and the online replay buffer in the agent's proportion."""
    cfg = run.cfg
    if run.online_steps == 0 or state.online_done >= run.online_steps:
        return agent
    if run.fresh_online and state.online_done == 0:
        agent = run.new_agent(run.seed + 1)
    state.online_started = True
    metrics, total = Metrics(state, run.logger, cfg.log_interval, run.bar), run.offline_steps + run.online_steps
    ratio = cfg.offline_ratio if cfg.offline_ratio is not None else agent.default_offline_ratio
    start_steps = cfg.start_steps if cfg.start_steps is not None else agent.default_start_steps
    n_off, n_on = agent.online_split(ratio)
    act_key, action_dim = jax.random.PRNGKey(run.seed + 7919), run.example["actions"].shape[-1]
    needs_mc = "mc_returns" in run.sampler.keys
    env = make_task_env(run.task_id, cfg.frame_stack)
    obs, _ = env.reset(seed=run.seed * 1_000_003 + state.episode)
    if state.buffer is None:
        state.buffer = run.buffer(obs)
    ep_idx, ep_rew, ckpt_due = [], [], False
    while state.online_done < run.online_steps:
        if state.online_done < start_steps:
            action = state.rng.uniform(-1, 1, action_dim).astype(np.float32)
        else:
            action = np.asarray(agent.sample_actions(obs, seed=jax.random.fold_in(act_key, state.online_done)))
        next_obs, reward, term, trunc, _ = env.step(action)
        ep_idx.append(state.buffer.insert(obs, action, reward, 1.0 - float(term), next_obs))
        ep_rew.append(float(reward))
        obs = next_obs
        state.online_done += 1
        prev, state.step = state.step, state.step + 1
        if state.online_done > start_steps and len(state.buffer) > 0:
            online = as_batch(state.buffer.sample(n_on, state.rng), run.sampler.keys)
            batch = agent.mix_online(run.sampler.sample(n_off, state.rng), online) if n_off else online
            agent, info = agent.update_donated(batch)
            metrics.record(info, 1)
        run.bar.update(1)
        metrics.maybe_log(prev)
        ckpt_due |= crossed(prev, state.step, cfg.checkpoint_interval)
        if crossed(prev, state.step, cfg.eval_interval) and state.step < total:
            run.evaluate(agent, state, cfg.eval_episodes)
        if term or trunc:
            state.buffer.end_episode()
            if needs_mc:
                tail = mc_tail(ep_rew[-1], run.sampler.mc_gamma, bool(term))  # as the offline data's returns
                state.buffer.set_mc_returns(ep_idx, ep_rew, run.sampler.mc_gamma, bootstrap=tail)
            run.logger.log(state.step, {"train/episode_return": sum(ep_rew), "train/episode_length": len(ep_rew)})
            ep_idx, ep_rew = [], []
            state.episode += 1
            if ckpt_due or state.online_done == run.online_steps:
                run.checkpoint(agent, state)
                ckpt_due = False
            obs, _ = env.reset(seed=run.seed * 1_000_003 + state.episode)
    env.close()
    run.checkpoint(agent, state)
    return agent


def load_run(run_dir: str | Path):
    """``(agent, resolved_config)`` from a run directory's config and latest checkpoint."""
    run_dir = Path(run_dir)
    resolved = RunDir(run_dir).read_config()
    ckpt = load_checkpoint(run_dir)
    if ckpt is None:
        raise RunDirError(f"{run_dir} has no checkpoint yet", "wait for the first checkpoint or train longer")
    agent_cls, agent_config_fn = get_agent(resolved["algo"])
    was = resolved.get("agent_version", 1)
    if was != agent_cls.version:  # its networks and config keys may be another version's
        raise RunDirError(
            f"{run_dir} was trained by {resolved['algo']} v{was}; this d5rl's is v{agent_cls.version}",
            "evaluate it with the d5rl that trained it, or train it again",
        )
    cfg = Config(resolved["agent"])
    env = make_task_env(resolved["task_id"], resolved["train"]["frame_stack"])
    obs, _ = env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    env.close()
    agent = agent_cls.create(resolved["seed"], obs, action, cfg)
    return restore_agent(agent, ckpt), resolved
