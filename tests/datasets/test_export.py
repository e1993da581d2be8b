import numpy as np
import pytest

from d5rl.datasets.export import export_minari
from d5rl.datasets.loading import load_dataset
from tests.datasets.toy import register_toy

minari = pytest.importorskip("minari")


def test_minari_round_trip(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    spec = register_toy("minari", num_episodes=5, per_shard=2)
    ds = load_dataset(spec, progress=False)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every metadata field minari asks for is given: no warning to read
        export_minari(spec.id, dataset_id="d5rltest/toy-v0", progress=False)
    md = minari.load_dataset("d5rltest/toy-v0")
    assert md.total_episodes == 5 and md.total_steps == ds.num_transitions
    for i, ep in enumerate(md.iterate_episodes()):
        ours = ds.episode(i).arrays
        np.testing.assert_array_equal(ep.observations, ours["observations"])
        np.testing.assert_array_equal(ep.actions, ours["actions"])
        np.testing.assert_allclose(ep.rewards, ours["rewards"])
        np.testing.assert_array_equal(ep.terminations, ours["terminals"])
        np.testing.assert_array_equal(ep.truncations, ours["timeouts"])
    assert (tmp_path / "minari").is_dir() and list((tmp_path / "minari").rglob("*.hdf5"))  # where it was told


def test_minari_export_of_pixels_is_lossless_and_matches_its_env(tmp_path, monkeypatch):
    import d5rl
    from d5rl.datasets.export import d5rl_key

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    task = "wx-sorting-pickplacedata-v0"
    ds = load_dataset(task, episodes=1, workers=1, progress=False)
    export_minari(task, dataset_id="d5rltest/wx-v0", progress=False)
    md = minari.load_dataset("d5rltest/wx-v0")
    env = d5rl.make_env(task)
    assert md.action_space == env.action_space  # Box(-1, 1), not Box(-inf, inf)
    assert sorted(md.observation_space.spaces) == ["pixels__side", "proprio"]
    for k, space in md.observation_space.spaces.items():
        assert space == env.observation_space[d5rl_key(k)]
    ep = next(md.iterate_episodes())
    ours = ds.episode(0).arrays
    np.testing.assert_array_equal(ep.observations["pixels__side"], ours["observations/pixels/side"])  # no JPEG
    np.testing.assert_array_equal(ep.observations["proprio"], ours["observations/proprio"])
    recovered = md.recover_environment()
    obs, _ = recovered.reset(seed=0)
    assert sorted(obs) == sorted(md.observation_space.spaces) and md.observation_space.contains(obs)
    assert recovered.spec.max_episode_steps == d5rl.get_spec(task).max_episode_steps
    recovered.close()


def test_a_minari_export_names_an_env_gymnasium_makes_and_carries_the_infos_a_score_needs(tmp_path, monkeypatch):
    import gymnasium

    import d5rl

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    task = "kitchen-standard-mixed-state-v0"
    ds = load_dataset(task, episodes=2, workers=1, progress=False)
    export_minari(task, dataset_id="d5rltest/kitchen-v0", progress=False)
    md = minari.load_dataset("d5rltest/kitchen-v0")
    env = gymnasium.make(md.spec.env_spec.id)
    assert env.spec.max_episode_steps == d5rl.get_spec(task).max_episode_steps
    env.close()
    cols = [d5rl.envs.kitchen.subtasks.SUBTASK_NAMES.index(t) for t in d5rl.envs.kitchen.subtasks.MIXED]
    for i, ep in enumerate(md.iterate_episodes()):
        done = np.asarray(ds.episode(i).arrays["infos/completed"])
        assert ep.infos["completed"].shape == (len(done) + 1,) + done.shape[1:]  # the reset's row, then each step's
        np.testing.assert_array_equal(ep.infos["completed"][1:], done)
        # the task's score from the Minari file alone: target subtasks done at the episode's end
        assert ep.infos["completed"][-1][cols].mean() == done[-1][cols].mean()
