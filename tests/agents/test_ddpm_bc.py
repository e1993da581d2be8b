import jax
import numpy as np

from tests.agents.helpers import batch, dataset, make_agent, train


def initial_loss(agent):
    """Noise-prediction loss of the untrained model (≈ action_dim = 2)."""
    _, m = agent.update(batch(dataset(), agent.config.batch_size, np.random.default_rng(9)))
    return float(m["actor/loss"])


def test_ddpm_bc_noise_loss_falls():
    agent = make_agent("ddpm_bc")
    first = initial_loss(agent)
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["actor/loss"] < 0.6 * first
    obs = dataset().observations[:4]
    a = np.asarray(agent.eval_actions(obs, seed=jax.random.PRNGKey(0)))
    assert a.shape == (4, 2) and np.all(np.abs(a) <= 1)
