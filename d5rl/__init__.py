"""d5rl: the D5RL offline RL benchmark, with datasets generated on your machine.

import d5rl
env, dataset = d5rl.make("a1-walk-v0")
"""

from __future__ import annotations

from d5rl.errors import D5RLError
from d5rl.registry import episode_score, get_spec, list_tasks, make_env, normalize_score, parse_task_id, register_all
from d5rl.version import __version__

# Every task is a Gymnasium id from here on: gymnasium.make("d5rl/a1-walk-v0") works after `import d5rl`.
# (Registration imports no MuJoCo and no JAX; XLA flags are set only by d5rl.agents, where d5rl trains.)
register_all()


def load_dataset(task_id: str, **kwargs):
    """The task's offline dataset (see :func:`d5rl.datasets.loading.load_dataset`)."""
    from d5rl.datasets.loading import load_dataset as _load  # start-up time: `import d5rl` stays light

    return _load(task_id, **kwargs)


def make(task_id: str, *, generate: bool = True, dataset_kwargs: dict | None = None, **env_kwargs):
    """``(env, dataset)`` for a task.

    If the dataset is not on disk yet and ``generate`` is true, it is generated
    first (deterministically, with a progress bar); pass ``generate=False`` to get
    a :class:`~d5rl.errors.DatasetNotFoundError` instead.
    """
    env = make_env(task_id, **env_kwargs)
    dataset = load_dataset(task_id, generate=generate, **(dataset_kwargs or {}))
    return env, dataset


__all__ = [
    "D5RLError",
    "__version__",
    "episode_score",
    "get_spec",
    "list_tasks",
    "load_dataset",
    "make",
    "make_env",
    "normalize_score",
    "parse_task_id",
]
