import numpy as np
import pytest

from tests.agents.helpers import batch, dataset, make_agent, train


def test_cql_conservative_term_falls():
    agent = make_agent("cql")
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["critic/cql_loss"] < hist[0]["critic/cql_loss"]
    assert hist[-1]["critic/loss"] < hist[0]["critic/loss"]
    # the regulariser pushes Q of out-of-distribution actions below the data Q's log-sum-exp bound
    assert all(np.isfinite(v) for v in hist[-1].values())


def test_calql_bounds_policy_q_by_mc_returns():
    agent = make_agent("calql")
    b = batch(dataset(), 64, np.random.default_rng(0))
    _, m = agent.update(b)
    assert 0.0 <= float(m["critic/bound_rate"]) <= 1.0
    # with huge Monte-Carlo returns every policy Q is lifted, and the OOD estimate follows
    high = {**b, "mc_returns": np.full(64, 100.0, np.float32)}
    _, m_high = agent.update(high)
    assert float(m_high["critic/bound_rate"]) == 1.0
    assert float(m_high["critic/ood_q"]) > 90.0
    no_mc = {k: v for k, v in b.items() if k != "mc_returns"}
    with pytest.raises(KeyError, match="mc_returns"):
        agent.update(no_mc)


def test_calql_loss_falls():
    agent = make_agent("calql")
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["critic/loss"] < hist[0]["critic/loss"]
