"""Reference offline-RL agents in JAX (install the ``train`` extra: ``pip install d5rl[train]``).

Every agent has the same interface::

    agent = IQLAgent.create(seed, example_observations, example_actions, config)
    agent, metrics = agent.update(batch)        # jitted; batch: observations, actions, rewards, masks, next_observations
    actions = agent.sample_actions(obs, seed=key)   # exploration
    actions = agent.eval_actions(obs)               # evaluation

``get_agent(name)`` returns ``(AgentClass, get_config)`` for one of :data:`AGENTS`.
"""

from __future__ import annotations

import importlib

from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.xla_flags import configure_default_flags

configure_default_flags()  # d5rl trains from here on: its XLA:CPU flags, before JAX starts (never the user's)

# name -> (module, class)
AGENTS = {
    "bc": ("d5rl.agents.bc", "BCAgent"),
    "iql": ("d5rl.agents.iql", "IQLAgent"),
    "cql": ("d5rl.agents.cql", "CQLAgent"),
    "calql": ("d5rl.agents.calql", "CalQLAgent"),
    "td3bc": ("d5rl.agents.td3bc", "TD3BCAgent"),
    "rlpd": ("d5rl.agents.rlpd", "RLPDAgent"),
    "ddpm_bc": ("d5rl.agents.ddpm_bc", "DDPMBCAgent"),
    "idql": ("d5rl.agents.idql", "IDQLAgent"),
    # modern baselines beyond the paper's eight
    "fql": ("d5rl.agents.fql", "FQLAgent"),
    "rebrac": ("d5rl.agents.rebrac", "ReBRACAgent"),
}


class UnknownAgentError(D5RLError, KeyError):
    """An algorithm name that :data:`AGENTS` does not know."""


def canonical_name(name: str) -> str:
    """``TD3+BC`` -> ``td3bc``, ``ddpm-bc`` -> ``ddpm_bc``: the names of :data:`AGENTS` (others pass through)."""
    key = name.strip().lower().replace("-", "_").replace("+", "")
    return {"td3_bc": "td3bc", "ddpmbc": "ddpm_bc", "cal_ql": "calql"}.get(key, key)


def get_agent(name: str):
    """``(AgentClass, get_config)`` for an agent name (``bc``, ``iql``, ``cql``, ...)."""
    key = canonical_name(name)
    if key not in AGENTS:
        raise UnknownAgentError(f"unknown agent {name!r}", f"choose one of {', '.join(AGENTS)}")
    try:
        module = importlib.import_module(AGENTS[key][0])
    except ImportError as e:  # jax/flax/optax missing
        raise MissingDependencyError(
            f"agent {key} needs JAX, Flax and Optax ({e})", "install the training extra: pip install 'd5rl[train]'"
        ) from e
    return getattr(module, AGENTS[key][1]), module.get_config
