"""The nearest-neighbour probe: exact neighbour means, and it follows good data closed-loop."""

import numpy as np
import pytest

from d5rl.errors import D5RLError
from d5rl.production.probe import NearestNeighbourPolicy
from d5rl.production.toy.data import toy_dataset
from d5rl.training.evaluation import evaluate


def test_acts_with_the_mean_action_of_the_k_nearest_standardised_observations():
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(50, 3)) * np.array([1.0, 100.0, 0.01])  # scales that standardising must undo
    act = rng.uniform(-1, 1, (50, 2))
    policy = NearestNeighbourPolicy(obs, act, k=3)
    queries = rng.normal(size=(4, 3)) * np.array([1.0, 100.0, 0.01])
    z = (obs - obs.mean(0)) / (obs.std(0) + 1e-6)
    for q, a in zip(queries, policy(queries)):
        d = np.sum(((q - obs.mean(0)) / (obs.std(0) + 1e-6) - z) ** 2, axis=1)
        np.testing.assert_allclose(a, act[np.argsort(d)[:3]].mean(0), rtol=1e-6)
    np.testing.assert_array_equal(policy(obs[7]), policy(obs[7:8]))  # one observation or a batch of one


def test_follows_expert_data_and_beats_random_actions():
    ds = toy_dataset(100, seed=0, expert_prob=1.0, noise=0.1)
    nn = evaluate(
        NearestNeighbourPolicy(ds.observations, ds.arrays["actions"], k=5), "toy-reach-v0", 10, seed=5, num_envs=10
    )

    class Random:
        def eval_actions(self, obs, seed=None):
            return np.random.default_rng(0).uniform(-1, 1, (len(obs), ds.arrays["actions"].shape[1]))

    rnd = evaluate(Random(), "toy-reach-v0", 10, seed=5, num_envs=10)
    assert nn["score"] > rnd["score"] + 0.5, (nn["score"], rnd["score"])


def test_refuses_pixels_and_bad_k():
    with pytest.raises(D5RLError, match="flat state observations"):
        NearestNeighbourPolicy({"pixels": np.zeros((4, 8, 8, 3))}, np.zeros((4, 2)))
    with pytest.raises(D5RLError, match="k=9"):
        NearestNeighbourPolicy(np.zeros((4, 2)), np.zeros((4, 2)), k=9)
