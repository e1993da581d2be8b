"""Cal-QL: Calibrated Q-Learning (Nakamoto et al., 2023).

CQL whose conservative term never pushes the Q-values of policy actions below
a reference value: inside the log-sum-exp, Q(s, a~π) is replaced by
max(Q(s, a~π), G(s)), with G the Monte-Carlo discounted return of the dataset
trajectory from s (``batch['mc_returns']``; the training loop samples it with
the agent's discount).  An episode cut by its time limit continues, for G, with its
last reward held forever (r_T / (1 − γ), the D5RL release's tail:
:meth:`d5rl.datasets.dataset.Dataset.mc_returns`).  For online transitions the loop
supplies the return of the collected episode, with the same tail.  Everything else is
:class:`~d5rl.agents.cql.CQLAgent` (the release's form).

Extra metric: ``critic/bound_rate`` (share of policy Q-values that were lifted).
"""

from __future__ import annotations

import jax.numpy as jnp

from d5rl.agents.config import Config
from d5rl.agents.cql import CQLAgent
from d5rl.agents.cql import get_config as cql_config


class CalQLAgent(CQLAgent):
    extra_batch_keys = ("mc_returns",)  # Monte-Carlo returns of the data (and of finished online episodes)
    version = 2  # 2: CQL's release form and the time-limit tail in G (1: no tail)

    def bound_policy_q(self, q, batch):
        if "mc_returns" not in batch:
            raise KeyError("Cal-QL needs batch['mc_returns'] (sample the dataset with mc_gamma=discount)")
        lower = batch["mc_returns"][None, None, :]
        rate = jnp.mean(q < lower)
        return jnp.maximum(q, lower), {"critic/bound_rate": rate}


def get_config() -> Config:
    c = cql_config().to_dict()
    c.update(
        agent_name="calql",  # name in d5rl.agents.AGENTS
        cql_alpha=5.0,  # α (Cal-QL kitchen: 5; D5RL sweeps 0.1, 1, 5, 10)
    )
    return Config(c)
