import jax
import numpy as np
import pytest

from d5rl.agents import AGENTS
from tests.agents.helpers import batch, dataset, make_agent


@pytest.mark.parametrize("name", ["iql", "rlpd", "td3bc"])
def test_agent_bytes_roundtrip_continues_identically(name):
    a = make_agent(name)
    b = batch(dataset(), 64 * a.config.get("utd_ratio", 1), np.random.default_rng(0))
    a, _ = a.update(b)
    data = a.to_bytes()
    restored = make_agent(name, seed=123).from_bytes(data)  # different init, same structure
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(restored)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    a2, m2 = a.update(b)
    r2, n2 = restored.update(b)
    for x, y in zip(jax.tree_util.tree_leaves(a2), jax.tree_util.tree_leaves(r2)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert {k: float(v) for k, v in m2.items()} == {k: float(v) for k, v in n2.items()}


def test_every_agent_has_commented_config():
    import inspect

    from d5rl.agents import get_agent

    for name in AGENTS:
        _, get_config = get_agent(name)
        cfg = get_config()
        assert cfg.agent_name == name
        src = inspect.getsource(inspect.getmodule(get_config))
        body = src[src.index("def get_config") :]
        for line in body.splitlines():
            if "=" in line and line.strip().endswith(",") and "(" not in line.split("=")[0]:
                key = line.strip().split("=")[0]
                assert "#" in line or key.startswith("**"), f"{name}: config key {key} has no comment"
