"""Pixel observations (two 16×16 cameras, 3 stacked frames, proprio) through every agent."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from d5rl.agents import AGENTS
from d5rl.production.toy.data import toy_dataset
from tests.agents.helpers import make_agent

_DS = {}


def pixel_batch(n, seed=0):
    if "ds" not in _DS:
        _DS["ds"] = toy_dataset(8, pixels=True)
    b = _DS["ds"].sample(n, np.random.default_rng(seed), frame_stack=3, mc_gamma=0.99)
    keep = ("observations", "actions", "rewards", "masks", "next_observations", "mc_returns")
    return {k: (b[k] if isinstance(b[k], dict) else np.asarray(b[k], np.float32)) for k in keep}


def check_agent(name):
    b = pixel_batch(16)
    assert b["observations"]["pixels/front"].shape == (16, 16, 16, 9)
    agent = make_agent(name, _DS["ds"], batch_size=8, **({"num_samples": 2} if name == "idql" else {}))
    agent = type(agent).create(0, b["observations"], b["actions"], agent.config)
    per = 8 * agent.config.get("utd_ratio", 1)
    params0 = jax.tree_util.tree_leaves(agent.actor.params)
    agent, m = agent.update(jax.tree_util.tree_map(lambda x: x[:per], b))
    assert all(np.isfinite(float(v)) for v in m.values()), m
    changed = [not np.allclose(a, c) for a, c in zip(params0, jax.tree_util.tree_leaves(agent.actor.params))]
    assert any(changed)
    single = jax.tree_util.tree_map(lambda x: x[0], b["observations"])
    a = np.asarray(agent.sample_actions(single, seed=jax.random.PRNGKey(0)))
    assert a.shape == (2,) and np.all(np.abs(a) <= 1)
    assert np.asarray(agent.eval_actions(b["observations"])).shape == (16, 2)
    keys = jax.random.split(jax.random.PRNGKey(1), 16)  # a key per row (evaluation): rows act alone
    rows = np.asarray(agent.eval_actions(b["observations"], seed=keys))
    first = jax.tree_util.tree_map(lambda x: x[:1], b["observations"])
    np.testing.assert_allclose(rows[:1], np.asarray(agent.eval_actions(first, seed=keys[:1])), atol=1e-5)


def test_pixel_bc():
    check_agent("bc")


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in AGENTS if n != "bc"])
def test_pixel_agents(name):
    check_agent(name)


def test_pixel_td3bc_delays_the_policy_like_the_state_agent():
    # pixel TD3+BC's update() runs a program with or without the actor step (no lax.cond: slow on
    # XLA:CPU); same schedule as the state agent
    b = pixel_batch(16)
    agent = make_agent("td3bc", _DS["ds"], batch_size=8)
    agent = type(agent).create(0, b["observations"], b["actions"], agent.config)
    batch = jax.tree_util.tree_map(lambda x: x[:8], b)
    actor_params = []
    for _ in range(4):
        agent, m = agent.update(batch)
        actor_params.append(jax.tree_util.tree_leaves(agent.actor.params))
        assert (float(m["actor/loss"]) != 0.0) == (len(actor_params) % 2 == 1)
    same = lambda p, q: all(np.array_equal(x, y) for x, y in zip(p, q))  # noqa: E731
    assert int(agent.critic.step) == 4 and int(agent.actor.step) == 2  # policy_freq = 2: steps 1 and 3
    assert same(actor_params[0], actor_params[1]) and not same(actor_params[1], actor_params[2])
    assert same(actor_params[2], actor_params[3])


def test_pixel_td3bc_host_schedule_matches_the_in_program_one():
    """update() picks one of two programs on the host; update_many() selects inside one program.
    Both must give the same agent."""
    b = pixel_batch(16)
    agent = make_agent("td3bc", _DS["ds"], batch_size=8)
    agent = type(agent).create(0, b["observations"], b["actions"], agent.config)
    batches = [jax.tree_util.tree_map(lambda x, i=i: x[8 * i : 8 * (i + 1)], b) for i in range(2)]
    one_by_one = agent
    for batch in batches:
        one_by_one, _ = one_by_one.update(batch)
    stacked = jax.tree_util.tree_map(lambda *x: np.stack(x), *batches)
    in_scan, _ = jax.tree_util.tree_map(jnp.copy, agent).update_many(stacked)  # donates its argument
    for x, y in zip(jax.tree_util.tree_leaves(one_by_one), jax.tree_util.tree_leaves(in_scan)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-4, atol=1e-5)
