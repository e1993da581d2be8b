"""Offline RL beats behaviour cloning on a suboptimal dataset of the toy reach task.

The dataset mixes 20% (noisy) expert steps with 80% uniformly random ones, so
cloning it walks slowly; IQL, CQL, TD3+BC, ReBRAC and FQL recover a much better
policy from the same data in 1,500 updates.
"""

import numpy as np
import pytest

from d5rl.production.toy.data import toy_dataset
from d5rl.training.evaluation import evaluate
from tests.agents.helpers import make_agent, train

OVERRIDES = {
    "bc": {},
    "iql": {"expectile": 0.9, "temperature": 10.0},
    "cql": {"cql_alpha": 1.0, "init_temperature": 0.1, "actor_lr": 3e-4},
    "td3bc": {},
    "rebrac": {},
    "fql": {
        "alpha": 1.0
    },  # this data is 80% random actions: a weak pull to the behaviour flow (FQL tunes alpha per task)
}


def score(name: str) -> float:
    ds = toy_dataset(100, seed=0, expert_prob=0.2, noise=0.3)
    agent = make_agent(name, ds, batch_size=128, **OVERRIDES[name])
    agent, _ = train(agent, ds, chunks=15, chunk=100)
    return evaluate(agent, "toy-reach-v0", 10, seed=5, num_envs=10)["score"]


@pytest.fixture(scope="module")
def bc_score():
    return score("bc")


@pytest.mark.parametrize("name", ["iql", "cql", "td3bc", "rebrac", "fql"])
def test_offline_rl_beats_bc(name, bc_score):
    s = score(name)
    assert np.isfinite(s)
    assert s > bc_score + 0.1, f"{name} scored {s:.3f}, BC {bc_score:.3f}"
