"""Which policy snapshot collected which episode of the A1 replay buffers (read from the committed
training logs).  Light on purpose: task registration reads the dataset sizes from here without
importing MuJoCo."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from d5rl.envs.a1.agents import POLICY_DIR
from d5rl.errors import D5RLError


@functools.cache
def agent_log(agent: str, policy_dir: str = str(POLICY_DIR)) -> dict:
    path = Path(policy_dir) / agent / "log.json"
    if not path.exists():
        raise D5RLError(
            f"the A1 data-collecting agent {agent!r} has no policy snapshots ({path} is missing)",
            f"train it: `python -m d5rl.envs.a1.experts train --agents {agent}` (needs the `train` extra)",
        )
    return json.loads(path.read_text())


ORDER_SEED = 0  # the fixed shuffle of the buffers' episodes (part of the generator version)


def episode_table(agents: tuple[str, ...]) -> list[tuple[str, int]]:
    """(agent, segment) of every dataset episode.

    The merged buffers are shuffled once with a fixed seed, so the first N episodes
    (``d5rl generate --episodes N``) are a uniform subsample of all stages of all agents
    rather than the first agent's random exploration; ``meta['training_step']`` keeps
    the chronology.
    """
    table = []
    for agent in agents:
        for seg_i, seg in enumerate(agent_log(agent)["segments"]):
            table += [(agent, seg_i)] * int(seg["episodes"])
    order = np.random.default_rng(ORDER_SEED).permutation(len(table))
    return [table[i] for i in order]


def num_episodes(agents: tuple[str, ...]) -> int:
    try:
        return len(episode_table(agents))
    except D5RLError:
        return 0
