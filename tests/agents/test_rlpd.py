import jax
import numpy as np

from tests.agents.helpers import batch, dataset, make_agent, train


def test_rlpd_utd_does_utd_critic_updates_per_call():
    agent = make_agent("rlpd", utd_ratio=4, batch_size=16)
    b = batch(dataset(), 64, np.random.default_rng(0))
    agent, m = agent.update(b)
    assert int(agent.critic.step) == 4 and int(agent.actor.step) == 1 and int(agent.temp.step) == 1
    assert np.asarray(
        agent.critic.apply_fn({"params": agent.critic.params}, b["observations"][:3], b["actions"][:3])
    ).shape == (10, 3)


def test_rlpd_critic_loss_falls_and_temperature_moves():
    agent = make_agent("rlpd")
    agent, hist = train(agent, dataset(), chunks=3, chunk=50)
    assert hist[-1]["critic/loss"] < 0.5 * hist[0]["critic/loss"]
    assert hist[-1]["actor/temperature"] < hist[0]["actor/temperature"]  # entropy above target → α falls


def test_rlpd_sampling():
    agent = make_agent("rlpd")
    obs = dataset().observations[:4]
    a = np.asarray(agent.sample_actions(obs, seed=jax.random.PRNGKey(3)))
    assert a.shape == (4, 2) and np.all(np.abs(a) <= 1)
    assert np.asarray(agent.sample_actions(obs[0], seed=jax.random.PRNGKey(3))).shape == (2,)
