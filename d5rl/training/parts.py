"""The parts :func:`d5rl.training.loop.train` is composed of: the run's changing state (checkpointed
as one object), the offline batch sampler (and its prefetcher), the metric accumulator and the evaluator."""

from __future__ import annotations

import collections
import copy
import dataclasses
import hashlib
import math
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

from d5rl.errors import D5RLError
from d5rl.training.evaluation import EvalProgress, evaluate
from d5rl.training.logger import Logger
from d5rl.training.replay import ReplayBuffer
from d5rl.training.rundir import RunDir

BATCH_KEYS = ("observations", "actions", "rewards", "masks", "next_observations")
FLOAT_KEYS = ("rewards", "masks", "mc_returns", "next_actions")


class NonFiniteLossError(D5RLError, FloatingPointError):
    """A loss or metric became NaN or infinite."""


@dataclasses.dataclass
class RunState:
    """What changes during a run besides the agent; with it, one checkpoint resumes a run exactly."""

    rng: np.random.Generator  # the loop's sampler of batches and random actions
    step: int = 0  # offline updates + online environment steps done
    online_done: int = 0  # online environment steps done
    episode: int = 0  # online episodes finished
    online_started: bool = False  # an online phase began (an agent without offline pretraining was re-made)
    metric_sums: dict = dataclasses.field(default_factory=dict)  # metrics since the last log row, times updates
    metric_count: int = 0  # updates in metric_sums
    buffer: ReplayBuffer | None = None  # the online replay buffer
    elapsed_before: float = 0.0  # wall seconds the run had spent in earlier processes, up to their last checkpoint
    started: float = dataclasses.field(default_factory=lambda: time.monotonic())  # this process's start (not saved)

    def elapsed(self) -> float:
        """Wall seconds of the run over every process that ran it (work after a process's last checkpoint is lost and
        not counted, but for an evaluation's finished episodes, which a resumed evaluation keeps)."""
        return self.elapsed_before + time.monotonic() - self.started

    def to_json(self) -> dict:
        return {
            "rng": self.rng.bit_generator.state,
            "step": self.step,
            "online_done": self.online_done,
            "episode": self.episode,
            "online_started": self.online_started,
            "metric_sums": dict(self.metric_sums),
            "metric_count": self.metric_count,
            "elapsed_s": round(self.elapsed(), 3),
        }

    @classmethod
    def from_json(cls, d: dict, buffer: ReplayBuffer | None = None) -> RunState:
        rng = np.random.default_rng()
        rng.bit_generator.state = d["rng"]
        return cls(
            rng,
            d["step"],
            d["online_done"],
            d["episode"],
            d["online_started"],
            dict(d["metric_sums"]),
            int(d["metric_count"]),
            buffer,
            float(d.get("elapsed_s", 0.0)),
        )  # older checkpoints: unknown, 0


class Sampler:
    """Offline batches as the agent wants them: stacked frames, float32 scalars, and the agent's extra
    keys (``mc_returns``: Monte-Carlo returns with the agent's discount; ``next_actions``: the data's
    action at the next step)."""

    EXTRA_KEYS = ("mc_returns", "next_actions")

    def __init__(self, dataset, frame_stack: int, extra_keys: tuple[str, ...], discount: float):
        unknown = [k for k in extra_keys if k not in self.EXTRA_KEYS]
        if unknown:
            raise ValueError(f"no sampler for batch keys {unknown}; it makes {self.EXTRA_KEYS}")
        self.dataset, self.frame_stack = dataset, int(frame_stack)
        self.keys = BATCH_KEYS + tuple(extra_keys)
        self.mc_gamma = float(discount) if "mc_returns" in self.keys else None

    def sample(self, n: int, rng: np.random.Generator | None, indices: np.ndarray | None = None) -> dict:
        """A batch of ``n`` random transitions (or of ``indices``, drawn earlier from ``rng``)."""
        extra = {"mc_gamma": self.mc_gamma} if self.mc_gamma is not None else {}
        if "next_actions" in self.keys:
            extra["next_actions"] = True
        b = self.dataset.sample(n, rng, frame_stack=self.frame_stack, indices=indices, **extra)
        return as_batch(b, self.keys)

    def sample_stacked(self, k: int, n: int, rng: np.random.Generator) -> dict:
        """``k`` batches of ``n`` on a leading axis (for ``update_many``)."""
        batch = self.sample(k * n, rng)
        return jax.tree_util.tree_map(lambda x: x.reshape((k, n) + x.shape[1:]), batch)


class Prefetcher:
    """Batches of ``n`` from a :class:`Sampler`, assembled ahead of use by ``threads`` background threads
    (pixel runs: gathering and stacking frames, which releases the GIL, overlaps the device's update).

    The batches are exactly those of calling ``sampler.sample(n, rng)`` in turn: the transitions are
    drawn here, in order, from a copy of ``rng``, and :meth:`next` leaves ``rng`` in the state after the
    batch it returns, so a checkpoint stores the state of the first batch not yet trained on and a
    resumed run trains on the same batches.  Only the gathering runs ahead."""

    def __init__(self, sampler: Sampler, n: int, rng: np.random.Generator, threads: int = 2, depth: int = 4):
        self.sampler, self.n, self.rng, self.depth = sampler, int(n), rng, int(depth)
        self._ahead = copy.deepcopy(rng)  # draws the batches' transitions, ahead of ``rng``
        self._pool = ThreadPoolExecutor(max(1, int(threads)), thread_name_prefix="d5rl-batches")
        self._pending: collections.deque = collections.deque()

    def _submit(self) -> None:
        idx = self.sampler.dataset.draw_indices(self.n, self._ahead)
        job = self._pool.submit(lambda: jax.device_put(self.sampler.sample(self.n, None, indices=idx)))
        self._pending.append((job, self._ahead.bit_generator.state))

    def next(self) -> dict:
        while len(self._pending) < self.depth:
            self._submit()
        job, after = self._pending.popleft()
        batch = job.result()  # re-raises an error of the thread that gathered it
        self.rng.bit_generator.state = after
        self._submit()
        return batch

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pending.clear()

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def as_batch(b: dict, keys) -> dict:
    return {
        k: b[k] if isinstance(b[k], dict) else np.asarray(b[k], np.float32 if k in FLOAT_KEYS else None) for k in keys
    }


class Metrics:
    """Averages the agent's metrics between log rows (the sums live in the run state, so a resumed
    run logs the same rows) and adds ``time/updates_per_s``; stops the run on a NaN or infinity."""

    def __init__(self, state: RunState, logger: Logger, interval: int, bar):
        self.state, self.logger, self.interval, self.bar = state, logger, int(interval), bar
        self.t0, self.n = time.perf_counter(), 0

    def record(self, metrics, n_updates: int) -> None:
        host = {k: float(v) for k, v in jax.device_get(metrics).items()}
        bad = [k for k, v in host.items() if not math.isfinite(v)]
        if bad:
            raise NonFiniteLossError(
                f"non-finite values at step {self.state.step}: {', '.join(f'{k}={host[k]}' for k in bad)}",
                "lower the learning rates (--set actor_lr=... critic_lr=...) or check the dataset for NaN rewards; "
                "the run can resume from its last checkpoint",
            )
        sums = self.state.metric_sums
        for k, v in host.items():
            sums[k] = sums.get(k, 0.0) + v * n_updates
        self.state.metric_count += n_updates
        self.n += n_updates

    def maybe_log(self, prev_step: int) -> None:
        s = self.state
        if crossed(prev_step, s.step, self.interval) and s.metric_count:
            row = {k: v / s.metric_count for k, v in s.metric_sums.items()}
            row["time/updates_per_s"] = self.n / max(time.perf_counter() - self.t0, 1e-9)
            self.logger.log(s.step, row)
            self.bar.set_postfix(ups=f"{row['time/updates_per_s']:.1f}", refresh=False)
            s.metric_sums, s.metric_count = {}, 0
            self.t0, self.n = time.perf_counter(), 0


class Evaluator:
    """Evaluates the agent on the task and logs ``eval/<task>/{return, return_std, length, success, score}`` and
    the task's episode statistics (``eval/<task>/subtask/microwave``, ...)."""

    def __init__(self, task_id: str, seed: int, frame_stack: int, cfg, logger: Logger, run_dir: RunDir):
        self.task_id, self.seed, self.frame_stack, self.cfg = task_id, seed, frame_stack, cfg
        self.logger, self.run_dir = logger, run_dir

    def __call__(self, agent, state: RunState, episodes: int) -> dict[str, Any]:
        """Evaluate ``agent`` at ``state.step``; an evaluation resumed from an earlier process adds that process's
        time on it to the run's wall time (``state.elapsed_before``)."""
        step = state.step
        video = self.run_dir.video(step) if self.cfg.save_video else None
        # a kill mid-evaluation loses at most one batch of episodes: the rerun of this step's evaluation, on the
        # same agent, resumes from the file (a 100-episode IDQL evaluation is an hour of CPU)
        progress = EvalProgress(self.run_dir.eval_progress, {"step": int(step), "agent_sha256": fingerprint(agent)})
        res = evaluate(
            agent,
            self.task_id,
            episodes,
            seed=evaluation_seed(self.seed),
            num_envs=self.cfg.eval_envs,
            frame_stack=self.frame_stack,
            processes=self.cfg.eval_processes,
            video_path=video,
            progress=progress,
        )
        state.elapsed_before += progress.earlier_s
        row = {k: res[k] for k in ("return", "return_std", "length", "success", "score") if k in res}
        self.logger.log(step, {f"eval/{self.task_id}/{k}": v for k, v in {**row, **res.get("stats", {})}.items()})
        return res


def evaluation_seed(run_seed: int) -> int:
    """The seed of every evaluation of the run with seed ``run_seed`` (its episodes reset with this seed, this
    seed + 1, ...): the same at every step, so the learning curve compares the agent on the same episodes."""
    return 10_000 * (int(run_seed) + 1)


def fingerprint(agent) -> str:
    """sha256 of the agent's arrays (dtype, shape and bytes of each leaf, in tree order).  Not of
    ``agent.to_bytes()``: msgpack does not write a restored agent's arrays in the same bytes."""
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(agent):
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def crossed(prev: int, now: int, interval: int) -> bool:
    """Whether a multiple of ``interval`` lies in ``(prev, now]``."""
    return interval > 0 and now // interval > prev // interval
