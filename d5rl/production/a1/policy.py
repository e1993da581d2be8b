"""The data-collecting agents' policies, replayed in pure numpy.

A snapshot is an ``.npz`` of the SAC actor's weights (``MLP_0/Dense_i/{kernel,bias}``,
``Dense_0`` = mean head, ``Dense_1`` = log-std head).  The forward pass avoids BLAS
(elementwise products and numpy's pairwise sums), so an action is the same bit
pattern in every process, with any thread count: dataset bytes depend only on seeds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d5rl.rollout import rollout

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0


def _matvec(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return (x[:, None] * w).sum(axis=0)


class SnapshotPolicy:
    """Tanh-squashed Gaussian policy from a saved actor; ``kind='random'`` is uniform actions."""

    def __init__(self, path: Path | None, action_dim: int = 12):
        self.action_dim = action_dim
        self.layers: list[tuple[np.ndarray, np.ndarray]] = []
        if path is None:
            self.kind = "random"
            return
        self.kind = "sac"
        with np.load(path) as z:
            p = {k: z[k].astype(np.float64) for k in z.files}
        i = 0
        while f"MLP_0/Dense_{i}/kernel" in p:
            self.layers.append((p[f"MLP_0/Dense_{i}/kernel"], p[f"MLP_0/Dense_{i}/bias"]))
            i += 1
        self.mean = (p["Dense_0/kernel"], p["Dense_0/bias"])
        self.log_std = (p["Dense_1/kernel"], p["Dense_1/bias"])

    def __call__(self, obs: np.ndarray, rng: np.random.Generator, deterministic: bool = False) -> np.ndarray:
        if self.kind == "random":
            return rng.uniform(-1.0, 1.0, self.action_dim).astype(np.float32)
        h = np.asarray(obs, dtype=np.float64)
        for w, b in self.layers:
            h = np.maximum(_matvec(h, w) + b, 0.0)
        mu = _matvec(h, self.mean[0]) + self.mean[1]
        if deterministic:
            return np.tanh(mu).astype(np.float32)
        log_std = np.clip(_matvec(h, self.log_std[0]) + self.log_std[1], LOG_STD_MIN, LOG_STD_MAX)
        return np.tanh(mu + np.exp(log_std) * rng.standard_normal(self.action_dim)).astype(np.float32)


def run_episodes(
    env, policy: SnapshotPolicy, episodes: int, seed: int, deterministic: bool = True, max_steps: int | None = None
) -> dict[str, list]:
    """Roll ``policy`` on ``env`` (an A1 task or a data agent's training env) for ``episodes`` episodes.

    Episode ``i`` resets with seed ``seed * 100_003 + i``; the policy's noise comes from
    ``np.random.default_rng(seed)``.  An episode ends when the env terminates or truncates, or after
    ``max_steps`` steps (for envs that do not truncate themselves).  Per episode: ``returns`` (the env's
    reward), ``speeds`` (mean forward speed from the first step, m/s), ``lengths`` and ``falls`` (ended by
    termination).
    """
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {"returns": [], "speeds": [], "lengths": [], "falls": []}

    def act(observations, live, steps):
        return [policy(observations[0], rng, deterministic=deterministic)]

    for i in range(episodes):
        speeds: list[float] = []
        (ep,) = rollout(
            [env],
            act,
            [seed * 100_003 + i],
            max_steps=max_steps,
            on_step=lambda s: speeds.append(s.info["forward_speed"]),
        )
        for k, v in (
            ("returns", ep.ret),
            ("speeds", float(np.mean(speeds))),
            ("lengths", ep.length),
            ("falls", ep.terminated),
        ):
            out[k].append(v)
    return out


def save_actor(params, path: Path) -> None:
    """Save a flax actor's params (float32) as a snapshot."""
    flat = {}

    def walk(tree, prefix):
        for k, v in tree.items():
            if isinstance(v, dict) or hasattr(v, "items"):
                walk(v, f"{prefix}{k}/")
            else:
                flat[f"{prefix}{k}"] = np.asarray(v, dtype=np.float32)

    walk(params, "")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **flat)
