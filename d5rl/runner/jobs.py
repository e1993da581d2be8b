"""The default per-cell job: d5rl's training loop.

A job is any importable ``f(cell, cell_dir) -> dict | None`` (``--job module:function``).
It trains ``cell.algo`` on ``cell.task`` for ``cell.offline_steps`` (+ ``cell.online_steps``)
with ``cell.seed`` and the agent overrides ``cell.overrides``, writes its logs into
``cell_dir`` (the eval log contract is in :mod:`d5rl.runner.logs`) and returns an
optional JSON-able summary that is stored in the ``done`` marker.
"""

from __future__ import annotations

from pathlib import Path

from d5rl.errors import MissingDependencyError
from d5rl.runner.grid import Cell


def train_job(cell: Cell, cell_dir: Path):
    """Run :func:`d5rl.training.loop.train` on the cell's run spec (:meth:`Cell.spec`) in ``cell_dir``."""
    try:
        from d5rl.training.loop import train  # the train extra (JAX): a grid of other jobs runs without it
    except ModuleNotFoundError as e:
        if e.name in ("jax", "flax", "optax"):
            raise MissingDependencyError(f"training needs {e.name}", "pip install 'd5rl[train]'") from e
        raise
    summary = train(cell.spec(), Path(cell_dir))
    if not isinstance(summary, dict):
        return None
    return {k: v for k, v in summary.items() if isinstance(v, (int, float, str, bool, type(None)))}


# The trainer resumes from its checkpoint in the cell directory (and truncates its logs to it), so a
# killed or failed attempt continues where it stopped instead of starting over.
train_job.resumable = True
