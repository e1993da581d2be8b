import jax
import numpy as np

from tests.agents.helpers import batch, dataset, make_agent, train


def initial_loss(agent):
    """Noise-prediction loss of the untrained model (≈ action_dim = 2)."""
    _, m = agent.update(batch(dataset(), agent.config.batch_size, np.random.default_rng(9)))
    return float(m["actor/loss"])


def test_idql_losses_fall_and_pick_argmax_q():
    agent = make_agent("idql", num_samples=16)
    first = initial_loss(agent)
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["actor/loss"] < 0.6 * first
    assert hist[-1]["critic/loss"] < hist[0]["critic/loss"]
    obs = dataset().observations[:3]
    key = jax.random.PRNGKey(7)
    chosen = np.asarray(agent.eval_actions(obs, seed=key))
    # the chosen action has the highest target Q among the N candidates of its observation
    from d5rl.agents.ddpm_bc import ddpm_sample

    p = agent.target_actor_params
    feats = np.repeat(np.asarray(agent.actor.apply_fn({"params": p}, obs, method="encode")), 16, axis=0)
    cands = ddpm_sample(agent.actor.apply_fn, p, feats, key, 2, agent.config.diffusion_steps)
    q = np.asarray(agent.critic.apply_fn({"params": agent.target_critic_params}, np.repeat(obs, 16, 0), cands)).min(0)
    best = np.asarray(cands).reshape(3, 16, 2)[np.arange(3), q.reshape(3, 16).argmax(1)]
    np.testing.assert_allclose(chosen, best, atol=1e-5)
