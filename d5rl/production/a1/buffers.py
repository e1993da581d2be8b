"""Which policy snapshot collected which episode of the A1 replay buffers (read from the published
training logs, :func:`d5rl.envs.a1.published.agent_log`)."""

from __future__ import annotations

import numpy as np

from d5rl.envs.a1.published import agent_log

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
