"""Shared test helpers for the training loop."""

import contextlib
import json

import jax
import numpy as np

from d5rl.training import loop

# a small network and a short evaluation: loop tests check behaviour, not learning
SMALL = {
    "hidden_dims": "32,32",
    "batch_size": "32",
    "eval_episodes": "2",
    "eval_envs": "2",
    "log_interval": "16",
    "progress": "false",
    "tensorboard": "false",
}


def overrides(**kw):
    """``key=value`` overrides: :data:`SMALL` with ``kw`` on top."""
    return [f"{k}={v}" for k, v in {**SMALL, **kw}.items()]


def leaves(agent):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(agent)]


def rows(run_dir):
    """The run's metrics rows without their timings (which differ between two runs of the same cell)."""
    out = []
    for line in (run_dir / "metrics.jsonl").read_text().splitlines():
        r = json.loads(line)
        out.append({k: v for k, v in r.items() if not k.startswith("time/")})
    return out


@contextlib.contextmanager
def interrupt_after_checkpoint(at_step: int):
    """Inside this block, the first checkpoint at or after ``at_step`` ends the run with KeyboardInterrupt,
    as a kill right after that checkpoint would."""
    real = loop.save_checkpoint

    def save(run_dir, ckpt):
        real(run_dir, ckpt)
        if ckpt.state["step"] >= at_step:
            raise KeyboardInterrupt(f"interrupted after the checkpoint at step {ckpt.state['step']}")

    loop.save_checkpoint = save
    try:
        yield
    finally:
        loop.save_checkpoint = real
