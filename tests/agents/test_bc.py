import numpy as np

from d5rl.envs.toy.data import toy_dataset
from tests.agents.helpers import make_agent, train


def test_bc_loss_falls_and_compiles_once():
    agent = make_agent("bc")
    agent, hist = train(agent, toy_dataset(50), chunks=3, chunk=100)
    assert hist[-1]["actor/loss"] < hist[0]["actor/loss"] - 0.1
    assert agent.update_many._cache_size() >= 1
    before = agent.update_many._cache_size()
    agent, _ = train(agent, toy_dataset(50), chunks=2, chunk=100)
    assert agent.update_many._cache_size() == before  # same avals after an update: no recompilation


def test_bc_fits_deterministic_expert():
    ds = toy_dataset(60, seed=1, expert_prob=1.0, noise=0.0)
    agent = make_agent("bc", ds, hidden_dims=(128, 128), actor_lr=1e-3, batch_size=128)
    agent, hist = train(agent, ds, chunks=6, chunk=250)
    assert hist[-1]["actor/mse"] < 0.01
    b = ds.sample(256, np.random.default_rng(5))
    err = np.mean(np.sum((np.asarray(agent.eval_actions(b["observations"])) - b["actions"]) ** 2, -1))
    assert err < 0.01
