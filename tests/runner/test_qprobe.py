"""The Q probe: exact numbers for a critic and a policy known in closed form, and every agent with a Q critic."""

import numpy as np
import pytest

from d5rl.agents import AGENTS, get_agent
from d5rl.errors import D5RLError
from d5rl.runner.qprobe import q_probe


class _Critic:
    params = {}

    @staticmethod
    def apply_fn(variables, obs, act):
        q = -((act - obs[:, :2]) ** 2).sum(-1)
        return np.stack([q, q + 1.0])  # two heads: the probe takes the lower


class _Agent:
    critic = _Critic()

    @staticmethod
    def eval_actions(obs, seed=None):
        return 0.5 * obs[:, :2]


def test_numbers_for_a_critic_and_policy_in_closed_form():
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (64, 3)).astype(np.float32)
    act = rng.uniform(-1, 1, (64, 2)).astype(np.float32)
    batch = {"observations": obs, "actions": act, "rewards": np.arange(64.0)}
    r = q_probe(_Agent(), batch, np.random.default_rng(1))
    uniform = np.random.default_rng(1).uniform(-1, 1, act.shape).astype(np.float32)
    q_data = -((act - obs[:, :2]) ** 2).sum(-1)
    q_pi = -0.25 * (obs[:, :2] ** 2).sum(-1)
    assert r["reward_mean"] == pytest.approx(31.5)
    assert r["q_data"] == pytest.approx(q_data.mean(), rel=1e-5)
    assert r["q_policy"] == pytest.approx(q_pi.mean(), rel=1e-5)
    assert r["q_uniform"] == pytest.approx(-((uniform - obs[:, :2]) ** 2).sum(-1).mean(), rel=1e-5)
    assert r["gap_data_policy"] == pytest.approx((q_data - q_pi).mean(), rel=1e-5)
    assert r["policy_action_distance"] == pytest.approx(np.abs(0.5 * obs[:, :2] - act).mean(), rel=1e-5)


def test_refuses_pixels_and_agents_without_a_critic():
    with pytest.raises(D5RLError, match="flat state observations"):
        q_probe(
            _Agent(),
            {"observations": {"pixels": np.zeros((2, 8, 8, 3))}, "actions": np.zeros((2, 2)), "rewards": np.zeros(2)},
            np.random.default_rng(0),
        )
    bc, config = get_agent("bc")
    agent = bc.create(0, np.zeros(3, np.float32), np.zeros(2, np.float32), config())
    with pytest.raises(D5RLError, match="no Q critic"):
        q_probe(
            agent,
            {
                "observations": np.zeros((2, 3), np.float32),
                "actions": np.zeros((2, 2), np.float32),
                "rewards": np.zeros(2),
            },
            np.random.default_rng(0),
        )


@pytest.mark.parametrize("algo", [a for a in AGENTS if a not in ("bc", "ddpm_bc")])
def test_every_agent_with_a_q_critic_can_be_probed(algo):
    cls, config = get_agent(algo)
    rng = np.random.default_rng(0)
    obs, act = rng.normal(size=(16, 5)).astype(np.float32), rng.uniform(-1, 1, (16, 3)).astype(np.float32)
    agent = cls.create(0, obs[0], act[0], config())
    r = q_probe(agent, {"observations": obs, "actions": act, "rewards": np.ones(16)}, rng)
    assert all(np.isfinite(v) for v in r.values()) and r["samples"] == 16
