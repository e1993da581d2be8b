"""A run's memory, checked before anything is allocated: a lower bound on what its networks and batches need
against what the device (or host) has."""

from __future__ import annotations

import jax
import numpy as np

from d5rl.agents.config import Config, ConfigError


def available_memory() -> int | None:
    """Bytes the agent's arrays can use: the accelerator's limit where JAX reports one, else the host's
    available memory (``MemAvailable``); None if neither is known."""
    try:
        stats = jax.devices()[0].memory_stats() or {}
    except Exception:  # noqa: BLE001 - CPU backends report nothing
        stats = {}
    if stats.get("bytes_limit"):
        return int(stats["bytes_limit"])
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def memory_floor(agent_cfg: Config, example: dict) -> int:
    """A lower bound on the bytes a run allocates: each network named by a ``*hidden_dims`` setting once, as
    float32 parameters with their gradient and two Adam moments, and one batch of its inputs and widest
    activations.  Every agent keeps more (critic ensembles, target networks), so a run above it cannot fit."""
    obs = example["observations"]
    obs_dim = sum(int(np.prod(np.shape(v)[1:])) for v in (obs.values() if isinstance(obs, dict) else [obs]))
    act_dim = int(np.prod(np.shape(example["actions"])[1:]))
    batch = int(agent_cfg.get("batch_size", 1))
    total = batch * 4 * 2 * (obs_dim + act_dim)  # observations and next observations of one batch
    for key, dims in agent_cfg.items():
        if key.endswith("hidden_dims") and isinstance(dims, tuple) and dims:
            widths = [min(obs_dim, 256) + act_dim, *map(int, dims), 1]
            params = sum(a * b + b for a, b in zip(widths, widths[1:]))
            total += 4 * 4 * params + 4 * batch * max(widths)
    return total


def check_memory(agent_cfg: Config, example: dict) -> None:
    """A one-line error, before anything is allocated or written, for network widths or a batch size that
    cannot fit (``--set hidden_dims=[1000000000]`` would otherwise fail deep in XLA and leave files behind)."""
    need, have = memory_floor(agent_cfg, example), available_memory()
    if have is not None and need > have:
        dims = {k: list(v) for k, v in agent_cfg.items() if k.endswith("hidden_dims")}
        raise ConfigError(
            f"networks {dims} with batch_size={agent_cfg.get('batch_size')} need at least "
            f"{need / 2**30:,.1f} GiB; {have / 2**30:,.1f} GiB are available",
            "lower them with --set hidden_dims=... batch_size=...",
        )
