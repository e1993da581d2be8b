"""The numpy toy tasks are registered like every other task."""

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import d5rl


def test_registered_env_dataset_and_score():
    for task in ("toy-reach-v0", "toy-reach-pixels-v0"):
        check_env(gymnasium.make(f"d5rl/{task}").unwrapped, skip_render_check=True)
        ds = d5rl.load_dataset(task, episodes=4, progress=False)
        assert ds.num_episodes == 4 and ds.num_transitions == 4 * 25
        assert d5rl.get_spec(task).observation == ("pixels" if "pixels" in task else "state")
    assert np.isclose(d5rl.normalize_score("toy-reach-v0", d5rl.get_spec("toy-reach-v0").score.expert), 1.0)
