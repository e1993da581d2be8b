"""What Gymnasium users expect of every family: envs pickle and deep-copy (vector envs, checkpointing
wrappers), and ``render()`` takes Gymnasium's ``width`` / ``height`` and ``render_mode`` the same way."""

import copy
import pickle

import gymnasium
import numpy as np
import pytest

import d5rl

# one task per env class; the copy must continue exactly as the original
TASKS = [
    "toy-reach-v0",
    "a1-walk-v0",
    "a1-walk-v1",
    "kitchen-standard-mixed-v0",
    "wx-sorting-v0",
    pytest.param("a1-hiking-v0", marks=pytest.mark.slow),  # builds its course: ~20 s
    pytest.param("kitchen-randomized-mixed-v0", marks=pytest.mark.slow),
]  # compiles a variant: ~30 s


def _leaves(x):
    return [np.asarray(v) for v in (x.values() if isinstance(x, dict) else [x])]


@pytest.mark.parametrize("task", TASKS)
def test_envs_pickle_deep_copy_and_render_at_gymnasiums_width_and_height(task):
    env = d5rl.make_env(task, render_mode="rgb_array", width=48, height=40)
    env.reset(seed=0)
    assert env.render().shape == (40, 48, 3)
    action = np.full(env.action_space.shape, 0.3, np.float32)
    env.step(action)
    for clone in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        a, b = env.unwrapped, clone.unwrapped
        if hasattr(a, "get_state"):
            np.testing.assert_array_equal(a.get_state(), b.get_state())
        for x, y in zip(_leaves(copy.deepcopy(env).step(action)[0]), _leaves(clone.step(action)[0])):
            np.testing.assert_array_equal(x, y)
        assert clone.render().shape == (40, 48, 3)
    env.close()


@pytest.mark.parametrize("task", ["toy-reach-v0", "wx-sorting-v0"])
def test_render_without_a_render_mode_warns_and_returns_none_in_every_family(task):
    env = d5rl.make_env(task)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    with pytest.raises(ValueError, match="width must be a number of pixels"):
        d5rl.make_env(task, render_mode="rgb_array", width=0)


def test_widowx_takes_a_render_size_like_the_other_families():
    env = d5rl.make_env("wx-sorting-v0", render_mode="rgb_array", render_size=(30, 50))
    env.reset(seed=0)
    assert env.render().shape == (30, 50, 3)
    assert isinstance(env, gymnasium.Env)
