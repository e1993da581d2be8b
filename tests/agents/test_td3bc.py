from tests.agents.helpers import dataset, make_agent, train


def test_td3bc_losses_fall_and_policy_is_delayed():
    agent = make_agent("td3bc")
    agent, hist = train(agent, dataset(), chunks=3, chunk=100)
    assert hist[-1]["critic/loss"] < 0.5 * hist[0]["critic/loss"]
    assert hist[-1]["actor/bc_mse"] < hist[0]["actor/bc_mse"]
    assert int(agent.critic.step) == 300
    assert int(agent.actor.step) == 150  # policy_freq = 2
