"""Per-task settings: one file (``d5rl/configs/settings.json``), one resolver.

Every command that trains or describes a run resolves its configuration here, once, into a
:class:`~d5rl.training.config.RunSpec` that the trainer takes whole, so ``d5rl train``, ``d5rl bench``,
``--show-config`` and the ``config.json`` that ``d5rl eval`` reads can never disagree.  Layers, lowest first:

agent config
    the agent's ``get_config()`` defaults; ``observations[obs]`` ("all", then the algorithm);
    ``groups[group][obs]`` ("all", then the algorithm); the user's ``--set`` values.
training-loop config
    :func:`d5rl.training.config.get_train_config` defaults; ``protocol[group]``; ``--set``;
    then what follows from the task (``frame_stack`` 3 for pixels, 1 for states) and, through the
    agent's :meth:`~d5rl.agents.common.Agent.resolve_config`, from the run's length (IQL's "auto"
    policy-lr decay over the offline steps of an offline-only run).

``group`` and ``obs`` are the task's :attr:`~d5rl.registry.TaskSpec.benchmark_group` and
:attr:`~d5rl.registry.TaskSpec.observation`.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from d5rl.agents import canonical_name, get_agent
from d5rl.agents.config import AGENT_BOUNDS, check_bounds
from d5rl.errors import D5RLError
from d5rl.registry import get_spec
from d5rl.training.config import TRAIN_BOUNDS, RunSpec, get_train_config, split_overrides

SETTINGS_PATH = Path(__file__).resolve().parent / "configs" / "settings.json"


@functools.lru_cache(maxsize=1)
def table() -> dict:
    return json.loads(SETTINGS_PATH.read_text())


def _plain(d: Mapping | None) -> dict:
    return {k: v for k, v in (d or {}).items() if not k.startswith("_")}


def task_keys(task_id: str) -> tuple[str, str]:
    """``(group, observation)`` of a task."""
    spec = get_spec(task_id)
    return spec.benchmark_group, spec.observation


def layers(task_id: str, algo: str, agent_keys=None) -> tuple[dict, dict]:
    """``(agent values, training-loop values)`` the settings file gives a task and algorithm; "all"
    entries apply the keys the agent has (``agent_keys``; every key if None)."""
    algo = canonical_name(algo)
    group, obs = task_keys(task_id)
    data = table()
    agent: dict[str, Any] = {}
    for section in (data["observations"].get(obs, {}), data["groups"].get(group, {}).get(obs, {})):
        agent.update({k: v for k, v in _plain(section.get("all")).items() if agent_keys is None or k in agent_keys})
        agent.update(_plain(section.get(algo)))
    return agent, _plain(data["protocol"].get(group))


def resolve(
    algo: str,
    task_id: str,
    overrides: Iterable[str] | Mapping[str, Any] | None = None,
    *,
    offline_steps: int = 0,
    online_steps: int = 0,
    seed: int = 0,
    tuned: bool = True,
) -> RunSpec:
    """The run spec of one run: its agent and training-loop configs (``tuned=False``: the agent's own
    defaults), step counts and seed."""
    agent_cls, config_fn = get_agent(algo)
    defaults = config_fn()
    agent_layer, train_layer = layers(task_id, algo, defaults) if tuned else ({}, {})
    agent_cfg, train_cfg = defaults.override(agent_layer), get_train_config().override(train_layer)
    agent_cfg, train_cfg = split_overrides(overrides, agent_cfg, train_cfg)
    check_bounds(agent_cfg, AGENT_BOUNDS)
    check_bounds(train_cfg, TRAIN_BOUNDS)
    _, obs = task_keys(task_id)
    if train_cfg.frame_stack is None:
        train_cfg = train_cfg.replace(frame_stack=3 if obs == "pixels" else 1)
    elif train_cfg.frame_stack > 1 and obs != "pixels":
        raise D5RLError(
            f"frame_stack={train_cfg.frame_stack}: {task_id} observes states, and only camera frames are stacked",
            "drop --set frame_stack (state tasks take one observation)",
        )
    agent_cfg = agent_cls.resolve_config(agent_cfg, offline_steps=int(offline_steps), online_steps=int(online_steps))
    return RunSpec(
        agent_cfg.agent_name, task_id, agent_cfg, train_cfg, int(offline_steps), int(online_steps), int(seed)
    )


def run_steps(algo: str, offline_steps: int | None, online_steps: int) -> tuple[int, int]:
    """``(offline, online)`` steps a run really takes: agents that learn from the data only inside their
    online phase (RLPD: its online batches are half offline data) skip the offline phase of an
    offline-to-online run; ``None`` offline steps means the paper's 500k (or 0 for those agents)."""
    pretrains = getattr(get_agent(algo)[0], "offline_pretraining", True)
    if online_steps > 0 and not pretrains:
        return 0, int(online_steps)
    return (500_000 if offline_steps is None else int(offline_steps)), int(online_steps)
