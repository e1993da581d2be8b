import numpy as np

from d5rl.agents.common import observation_stats
from d5rl.production.toy.data import toy_dataset
from tests.agents.helpers import dataset, make_agent, train


def test_td3bc_losses_fall_and_policy_is_delayed():
    agent = make_agent("td3bc")
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["critic/loss"] < 0.5 * hist[0]["critic/loss"]
    assert hist[-1]["actor/bc_mse"] < hist[0]["actor/bc_mse"]
    assert int(agent.critic.step) == 300
    assert int(agent.actor.step) == 150  # policy_freq = 2


def test_td3bc_state_normalization_makes_training_shift_invariant():
    # TD3+BC standardises states with the dataset's statistics: a dataset whose observations are
    # shifted by a constant trains to the same policy (up to float rounding); without it, it does not
    def policy(shift: float, normalize: bool):
        ds = toy_dataset(50)
        ds.arrays["observations"] = ds.arrays["observations"] + np.float32(shift)
        mean, std = observation_stats(ds.observations) if normalize else (None, None)
        agent, _ = train(make_agent("td3bc", ds, obs_mean=mean, obs_std=std), ds, chunks=1, chunk=60)
        probe = toy_dataset(2, seed=9).observations[:16] + np.float32(shift)
        return np.asarray(agent.eval_actions(probe))

    assert np.abs(policy(0.0, True) - policy(50.0, True)).max() < 1e-2
    assert np.abs(policy(0.0, False) - policy(50.0, False)).max() > 0.1
