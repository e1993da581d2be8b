"""The default per-cell job: d5rl's training loop.

A job is any importable ``f(cell, cell_dir) -> dict | None`` (``--job module:function``).
It trains ``cell.algo`` on ``cell.task`` for ``cell.offline_steps`` (+ ``cell.online_steps``)
with ``cell.seed`` and the agent overrides ``cell.overrides``, writes its logs into
``cell_dir`` (the eval log contract is in :mod:`d5rl.runner.logs`) and returns an
optional JSON-able summary that is stored in the ``done`` marker.
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

from d5rl.errors import MissingDependencyError
from d5rl.runner.grid import Cell

# Where the training loop may live, first match wins.
TRAINER_CANDIDATES = ("d5rl.training.train:train", "d5rl.training.loop:train", "d5rl.training:train")


def find_trainer():
    errors = []
    for ref in TRAINER_CANDIDATES:
        module, _, attr = ref.partition(":")
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name in ("jax", "flax", "optax"):
                raise MissingDependencyError(f"training needs {e.name}", "pip install 'd5rl[train]'") from e
            errors.append(f"{module}: {e}")
            continue
        fn = getattr(mod, attr, None)
        if callable(fn):
            return fn
        errors.append(f"{module} has no {attr}")
    raise MissingDependencyError(
        "d5rl's training loop is not available (" + "; ".join(errors) + ")",
        "pass your own trainer with --job module:function",
    )


def train_job(cell: Cell, cell_dir: Path):
    """Run :func:`d5rl.training.loop.train` for one cell.

    The cell's protocol (``eval_interval``, ``eval_episodes``, ...) and agent
    overrides both go through the trainer's ``overrides`` (it routes each key to
    the agent's or the loop's config); the progress bar is off (the sweep has its own).
    """
    train = find_trainer()
    params = inspect.signature(train).parameters
    overrides = {"progress": False, **cell.protocol, **cell.overrides}
    kwargs = {"algo": cell.algo, "task_id": cell.task, "offline_steps": cell.offline_steps,
              "online_steps": cell.online_steps, "seed": cell.seed, "overrides": overrides,
              "run_dir": Path(cell_dir)}
    missing = [k for k in kwargs if k not in params]
    if missing:
        raise TypeError(f"the trainer {train.__module__}.{train.__name__} takes no {missing}")
    summary = train(**kwargs)
    if not isinstance(summary, dict):
        return None
    return {k: v for k, v in summary.items() if isinstance(v, (int, float, str, bool, type(None)))}


# The trainer resumes from its checkpoint in the cell directory (and truncates its logs to it), so a
# killed or failed attempt continues where it stopped instead of starting over.
train_job.resumable = True
