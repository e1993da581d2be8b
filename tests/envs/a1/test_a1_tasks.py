"""Tier 1 for every A1 task, v0 and v1: Gymnasium's checker, same seed same rollout, finite observations."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import d5rl

TASKS = d5rl.list_tasks("a1")


def test_every_a1_version_is_here():
    assert {"a1-walk-v0", "a1-hiking-v0", "a1-walk-v1", "a1-hiking-v1"} <= set(TASKS)


@pytest.mark.parametrize("task", TASKS)
def test_env_checker(task):
    env = d5rl.make_env(task)
    check_env(env.unwrapped, skip_render_check=True)
    assert f"d5rl/{task}" in gymnasium.registry


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_rollout_and_finite_obs(task):
    def rollout(seed):
        env = d5rl.make_env(task)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        out = [obs]
        for _ in range(30):
            obs, r, term, trunc, _ = env.step(rng.uniform(-1, 1, 12).astype(np.float32))
            out.append(np.append(obs, r))
            assert env.observation_space.contains(obs) and np.isfinite(obs).all()
            if term:
                break
        return out

    a, b, c = rollout(3), rollout(3), rollout(4)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))
