import numpy as np

from d5rl.production.toy.data import toy_dataset
from tests.agents.helpers import make_agent, train


def test_bc_loss_falls_and_compiles_once():
    agent, ds = make_agent("bc"), toy_dataset(50)
    b = ds.sample(512, np.random.default_rng(3))
    start = float(agent.actor_loss(agent.actor.params, b, agent.rng)[1]["actor/mse"])
    agent, hist = train(agent, ds, chunks=3, chunk=100)
    assert hist[-1]["actor/mse"] < start - 0.2 and hist[-1]["actor/loss"] < hist[0]["actor/loss"]
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


def test_bc_standardises_state_observations_when_asked():
    """normalize_observations (off by default): fit_config fills the dataset's mean and std, the loss and
    the policy see (obs - mean) / std, so a dataset shifted by a constant trains to the same policy."""
    from d5rl.agents.bc import BCAgent
    from tests.agents.helpers import small_config

    assert BCAgent.fit_config(small_config("bc"), toy_dataset(5)).obs_mean is None  # default: off

    def policy(shift: float, normalize: bool):
        ds = toy_dataset(50)
        ds.arrays["observations"] = ds.arrays["observations"] + np.float32(shift)
        cfg = BCAgent.fit_config(small_config("bc", normalize_observations=normalize), ds)
        if normalize:
            obs = np.asarray(ds.observations, np.float64)
            np.testing.assert_allclose(cfg.obs_mean, obs.mean(0), rtol=1e-6)
            np.testing.assert_allclose(cfg.obs_std, obs.std(0) + 1e-3, rtol=1e-6)
        b = ds.sample(1, np.random.default_rng(0))
        agent, _ = train(BCAgent.create(0, b["observations"], b["actions"], cfg), ds, chunks=1, chunk=60)
        probe = toy_dataset(2, seed=9).observations[:16] + np.float32(shift)
        return np.asarray(agent.eval_actions(probe))

    assert np.abs(policy(0.0, True) - policy(50.0, True)).max() < 1e-2
    assert np.abs(policy(0.0, False) - policy(50.0, False)).max() > 0.05
