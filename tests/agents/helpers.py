"""Small configs and a training helper shared by the agent tests."""

from __future__ import annotations

import numpy as np

from d5rl.agents import get_agent
from d5rl.production.toy.data import toy_dataset

KEYS = ("observations", "actions", "rewards", "masks", "next_observations", "mc_returns", "next_actions")

_DS = {}


def dataset(**kwargs):
    key = tuple(sorted(kwargs.items()))
    if key not in _DS:
        _DS[key] = toy_dataset(**{"num_episodes": 100, **kwargs})
    return _DS[key]


def small_config(name: str, **overrides):
    """The agent's default config with small networks (fast tests)."""
    _, get_config = get_agent(name)
    cfg = get_config()
    small = {"batch_size": 64}
    for k, v in (
        ("hidden_dims", (64, 64)),
        ("critic_hidden_dims", (64, 64)),
        ("actor_hidden_dims", (64, 64)),
        ("hidden_dim", 64),
        ("num_blocks", 2),
        ("cql_n_actions", 4),
        ("num_samples", 8),
        ("utd_ratio", 2),
        ("encoder_channels", (8, 8, 8)),
        ("actor_ema", 0.05),
    ):
        if k in cfg:
            small[k] = v
    small.update(overrides)
    return cfg.replace(**small)


def make_agent(name: str, ds=None, seed: int = 0, **overrides):
    cls, _ = get_agent(name)
    cfg = small_config(name, **overrides)
    ds = ds if ds is not None else dataset()
    b = ds.sample(1, np.random.default_rng(0))
    return cls.create(seed, b["observations"], b["actions"], cfg)


def batch(ds, n: int, rng, pixels: bool = False):
    b = ds.sample(n, rng, mc_gamma=0.99, next_actions=True)
    out = {}
    for k in KEYS:
        v = b[k]
        out[k] = v if isinstance(v, dict) else np.asarray(v, np.float32)
    return out


def train(agent, ds, chunks: int, chunk: int, seed: int = 0):
    """``chunks × chunk`` updates via ``update_many``; returns the agent and per-chunk mean metrics."""
    rng = np.random.default_rng(seed)
    per = agent.config.batch_size * agent.config.get("utd_ratio", 1)
    hist = []
    for _ in range(chunks):
        b = batch(ds, chunk * per, rng)
        b = {k: v.reshape((chunk, per) + v.shape[1:]) for k, v in b.items()}
        agent, m = agent.update_many(b)
        hist.append({k: float(v) for k, v in m.items()})
    return agent, hist
