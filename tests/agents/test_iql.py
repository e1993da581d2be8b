import jax
import numpy as np

from d5rl.agents.iql import expectile_loss
from tests.agents.helpers import dataset, make_agent, train


def test_expectile_loss_minimiser_is_the_expectile():
    x = np.random.default_rng(0).normal(size=2000)
    grid = np.linspace(-2, 2, 401)
    for tau in (0.5, 0.9):
        losses = [float(expectile_loss(x - m, tau).mean()) for m in grid]
        best = grid[int(np.argmin(losses))]
        if tau == 0.5:
            assert abs(best - x.mean()) < 0.02
        else:
            assert best > x.mean() + 0.5


def test_iql_losses_fall():
    agent = make_agent("iql")
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["critic/loss"] < 0.5 * hist[0]["critic/loss"]
    assert hist[-1]["actor/loss"] < hist[0]["actor/loss"]
    assert hist[-1]["value/v"] > hist[0]["value/v"]  # values grow towards the positive returns
    assert int(agent.critic.step) == int(agent.actor.step) == int(agent.value.step) == 300


def test_iql_actions_deterministic_in_eval():
    agent = make_agent("iql")
    obs = dataset().observations[:5]
    np.testing.assert_array_equal(np.asarray(agent.eval_actions(obs)), np.asarray(agent.eval_actions(obs)))
    a1 = agent.sample_actions(obs, seed=jax.random.PRNGKey(0))
    a2 = agent.sample_actions(obs, seed=jax.random.PRNGKey(1))
    assert not np.allclose(a1, a2)
    assert np.asarray(agent.eval_actions(obs[0])).shape == (2,)


def test_iql_policy_lr_decays_to_zero_over_actor_decay_steps():
    # IQL's offline runs decay the policy lr with a cosine schedule; after actor_decay_steps the policy stops moving
    def moved_after(decay_steps):
        agent, _ = train(make_agent("iql", actor_decay_steps=decay_steps), dataset(), chunks=1, chunk=40)
        before = [np.array(x) for x in jax.tree_util.tree_leaves(agent.actor.params)]  # copies: update_many donates
        agent, _ = train(agent, dataset(), chunks=1, chunk=20, seed=1)
        return any(
            not np.array_equal(a, np.asarray(b)) for a, b in zip(before, jax.tree_util.tree_leaves(agent.actor.params))
        )

    assert not moved_after(40)
    assert moved_after(0)
