"""The "-state" twins of the camera tasks: same data, observations = the env's state observation of each
stored simulator state."""

import numpy as np
import pytest

import d5rl


@pytest.mark.parametrize(
    "task, twin, dim, proprio",
    [
        ("kitchen-standard-mixed-v0", "kitchen-standard-mixed-state-v0", 30, 9),
        ("wx-sorting-pickplacedata-v0", "wx-sorting-pickplacedata-state-v0", 25, 8),
    ],
)
def test_state_twin_observes_the_stored_states(task, twin, dim, proprio):
    spec, pix = d5rl.get_spec(twin), d5rl.get_spec(task)
    assert spec.dataset == pix.dataset and spec.observation == "state" and pix.observation == "pixels"
    assert spec.benchmark_group == pix.benchmark_group
    ds = d5rl.load_dataset(twin, episodes=1, workers=1, progress=False)
    obs = np.asarray(ds.arrays["observations"])
    assert obs.shape == (ds.num_transitions + 1, dim) and obs.dtype == np.float32
    assert not (
        d5rl.load_dataset(twin, episodes=1, generate=False).arrays.keys()
        & {"observations/pixels/side", "observations/pixels/overview"}
    )
    # the first joints are the robot's (proprioception, stored with the data)
    np.testing.assert_array_equal(obs[:, :proprio], ds.arrays["observations/proprio"])
    # and each row is what the env observes when put in that state
    env = d5rl.make_env(twin).unwrapped
    env.reset(seed=0)
    if hasattr(env, "set_domain") and "domain" in ds.episode_meta[0]:
        from d5rl.envs.widowx import domain as wdom

        env.set_domain(wdom.Domain.from_json(ds.episode_meta[0]["domain"]))
    for i in (0, 7, ds.num_transitions):
        env.set_state(np.asarray(ds.arrays["states"][i]))
        np.testing.assert_array_equal(env._obs() if hasattr(env, "_obs") else env._get_obs(), obs[i])
    batch = ds.sample(8, np.random.default_rng(0))
    assert batch["observations"].shape == (8, dim) and batch["next_observations"].shape == (8, dim)
