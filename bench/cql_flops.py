"""Is state CQL as fast as its math allows?  Times one CQL (and CalQL) update against the matrix
products it cannot avoid, measured in the same process:

    python bench/cql_flops.py [--seconds 5]

Per update CQL evaluates both critics on 31 actions per state (the data action, 10 uniform,
10 from pi(s), 10 from pi(s')) plus a target evaluation at s', with gradients through all but the
target: the "floor" below is exactly those critic-MLP forward and backward matrix products
(batch 256, A1 sizes: 58-D observations, 12-D actions, 256-256 MLPs, two critics), jitted alone.
Ratio = update time / floor: 1.0 would mean everything else (actor, sampling, log-sum-exp,
Adam) is free.

Why CQL's critics take the concatenated (observation, action) input: computing the observation part of
the first layer once per state instead of once per sampled action (features @ K_f + actions @ K_a,
17% fewer FLOPs) makes the critic's forward + backward 1.4x *slower* on XLA:CPU (2-core x86 CPU:
257-264 vs 365-384 ms; a broadcast add of a (30, 256, 256) tensor and a K=12 matrix product cost more
than the FLOPs saved).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench.timing import rate

OBS, ACT, B, H, N = 58, 12, 256, 256, 10


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp

    from d5rl.agents import get_agent  # also sets d5rl's XLA flags

    rng = np.random.default_rng(0)
    batch = {
        "observations": rng.standard_normal((B, OBS), np.float32),
        "next_observations": rng.standard_normal((B, OBS), np.float32),
        "actions": rng.uniform(-0.99, 0.99, (B, ACT)).astype(np.float32),
        "rewards": rng.standard_normal(B).astype(np.float32),
        "masks": np.ones(B, np.float32),
        "mc_returns": rng.standard_normal(B).astype(np.float32),
    }

    # the floor: two critic MLPs on (1 + 3N) x B rows with gradients, plus the target on B rows
    rows = (1 + 3 * N) * B
    keys = jax.random.split(jax.random.PRNGKey(0), 6)
    w = [
        jax.random.normal(keys[0], (2, OBS + ACT, H)) * 0.1,
        jax.random.normal(keys[1], (2, H, H)) * 0.1,
        jax.random.normal(keys[2], (2, H, 1)) * 0.1,
    ]
    x = jax.random.normal(keys[3], (rows, OBS + ACT))
    xt = jax.random.normal(keys[4], (B, OBS + ACT))

    def mlp(w, x):
        h = jax.nn.relu(jnp.einsum("ni,qih->qnh", x, w[0]))
        h = jax.nn.relu(jnp.einsum("qnh,qhk->qnk", h, w[1]))
        return jnp.einsum("qnh,qhk->qnk", h, w[2])

    @jax.jit
    def floor(w, x, xt):
        target = jax.lax.stop_gradient(mlp(w, xt).min(0))
        return jax.grad(lambda w: (mlp(w, x) ** 2).mean() + target.mean())(w)

    t_floor = 1.0 / rate(lambda: jax.block_until_ready(floor(w, x, xt)), args.seconds)
    flops = 3 * 2 * 2 * rows * ((OBS + ACT) * H + H * H + H) + 2 * 2 * B * ((OBS + ACT) * H + H * H + H)
    print(f"floor (critic matmuls only): {t_floor * 1e3:7.1f} ms  ({flops / t_floor / 1e9:.1f} GFLOP/s)")
    for name in ("cql", "calql", "iql"):
        cls, config_fn = get_agent(name)
        agent = cls.create(0, batch["observations"][:1], batch["actions"][:1], config_fn())
        state = {"a": agent}

        def step():
            state["a"], m = state["a"].update(batch)
            jax.block_until_ready(m)

        t = 1.0 / rate(step, args.seconds)
        print(f"{name:6s} update: {t * 1e3:7.1f} ms  ratio to the CQL floor {t / t_floor:.2f}")


if __name__ == "__main__":
    main()
