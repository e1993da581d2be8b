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
