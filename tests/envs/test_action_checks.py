"""Every registered task refuses what it cannot simulate, before simulating anything."""

import gymnasium
import numpy as np
import pytest

import d5rl
from d5rl.envs.base import ActionError, ResetNeededError

# every registered task but the numpy toy ones (no simulator; for tests and smoke runs)
TASKS = [t for t in d5rl.list_tasks() if not t.startswith("test-") and d5rl.get_spec(t).benchmark_group != "toy"]
# one env per distinct entry point and kwargs (tasks that share both behave the same)
DISTINCT = list({(d5rl.get_spec(t).entry_point, repr(d5rl.get_spec(t).env_kwargs)): t for t in TASKS}.values())


@pytest.mark.parametrize("task", DISTINCT)
def test_bad_actions_and_step_before_reset(task):
    env = d5rl.make_env(task, **({"obs_mode": "state"} if "obs_mode" in _kwargs(task) else {}))
    shape = env.action_space.shape
    with pytest.raises(ResetNeededError, match="before reset") as e:
        env.step(np.zeros(shape, np.float32))
    assert isinstance(e.value, gymnasium.error.ResetNeeded)
    env.reset(seed=0)
    state = env.unwrapped.get_state()
    for bad in (np.full(shape, np.nan, np.float32), np.r_[np.zeros(shape[0] - 1), np.inf].astype(np.float32)):
        with pytest.raises(ActionError, match="NaN or infinite"):
            env.step(bad)
    with pytest.raises(ActionError, match="shape"):
        env.step(np.zeros(shape[0] + 1, np.float32))
    with pytest.raises(ActionError, match="complex values"):
        env.step(np.zeros(shape, np.complex64) + 0.5j)
    np.testing.assert_array_equal(env.unwrapped.get_state(), state)  # nothing was simulated
    # finite values outside [-1, 1] are clipped: the same step as the bound itself
    big = env.step(np.full(shape, 7.0, np.float32))[0]
    env.reset(seed=0)
    edge = env.step(np.ones(shape, np.float32))[0]
    for a, b in zip(_leaves(big), _leaves(edge)):
        np.testing.assert_array_equal(a, b)
    env.close()


def _kwargs(task):
    import inspect

    return inspect.signature(d5rl.registry.resolve(d5rl.get_spec(task).entry_point)).parameters


def _leaves(obs):
    return [obs[k] for k in sorted(obs)] if isinstance(obs, dict) else [obs]
