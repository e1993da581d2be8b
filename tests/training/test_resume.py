"""Exact resume after a kill (offline and online), and online fine-tuning."""

import json

import numpy as np
import pytest

from d5rl.training.loop import train
from tests.training.helpers import interrupt_after_checkpoint, leaves, overrides, rows
from d5rl.envs.toy.data import toy_dataset


def assert_offline_resume_is_exact(tmp_path, algo, task, steps, kw, ds, interrupt_at):
    """A run killed after its checkpoint at ``interrupt_at`` and resumed ends where an unbroken run does."""
    full = train(algo, task, steps, 0, 1, kw, tmp_path / "a", dataset=ds)
    with pytest.raises(KeyboardInterrupt), interrupt_after_checkpoint(interrupt_at):
        train(algo, task, steps, 0, 1, kw, tmp_path / "b", dataset=ds)
    first_sitting = json.loads((tmp_path / "b" / "checkpoint" / "state.json").read_text())["elapsed_s"]
    resumed = train(algo, task, steps, 0, 1, kw, tmp_path / "b", dataset=ds)
    for a, b in zip(leaves(full["agent"]), leaves(resumed["agent"])):
        np.testing.assert_array_equal(a, b)
    assert rows(tmp_path / "a") == rows(tmp_path / "b")
    assert (full["resumed"], resumed["resumed"]) == (False, True)
    assert first_sitting > 0 and resumed["run_wall_s"] >= first_sitting  # both sittings count


def test_offline_resume_is_exact(tmp_path):
    kw = overrides(checkpoint_interval=32, eval_interval=1000, updates_per_call=8)
    assert_offline_resume_is_exact(tmp_path, "td3bc", "toy-reach-v0", 96, kw, toy_dataset(20), 56)


@pytest.mark.slow  # ~1 min of pixel compiles; test_parts pins the generator contract it relies on in seconds
def test_pixel_offline_resume_is_exact_with_batches_gathered_ahead(tmp_path):
    """Pixel runs gather batches in background threads; a checkpoint still stores the generator state of
    the first batch not trained on, so a resumed run trains on the same batches."""
    kw = overrides(checkpoint_interval=6, eval_interval=1000, batch_size=8, eval_episodes=1, eval_envs=1)
    assert_offline_resume_is_exact(tmp_path, "bc", "toy-reach-pixels-v0", 12, kw, toy_dataset(6, pixels=True), 6)


def test_online_resume_is_exact_for_rlpd(tmp_path):
    ds = toy_dataset(10)
    kw = overrides(utd_ratio=2, batch_size=16, start_steps=10, checkpoint_interval=20, eval_interval=1000)
    full = train("rlpd", "toy-reach-v0", 0, 75, 2, kw, tmp_path / "a", dataset=ds)
    with pytest.raises(KeyboardInterrupt), interrupt_after_checkpoint(20):
        train("rlpd", "toy-reach-v0", 0, 75, 2, kw, tmp_path / "b", dataset=ds)
    state_step = json.loads((tmp_path / "b" / "checkpoint" / "state.json").read_text())["step"]
    assert state_step == 25  # the checkpoint due at step 20 waits for the episode end
    resumed = train("rlpd", "toy-reach-v0", 0, 75, 2, kw, tmp_path / "b", dataset=ds)
    for a, b in zip(leaves(full["agent"]), leaves(resumed["agent"])):
        np.testing.assert_array_equal(a, b)
    assert rows(tmp_path / "a") == rows(tmp_path / "b")
    returns = [r["train/episode_return"] for r in rows(tmp_path / "a") if "train/episode_return" in r]
    assert len(returns) == 3


def test_calql_online_finetuning_runs(tmp_path):
    ds = toy_dataset(10)
    res = train("calql", "toy-reach-v0", 16, 30, 0, overrides(cql_n_actions=2, eval_interval=1000), tmp_path / "c",
                dataset=ds)
    assert res["step"] == 46 and np.isfinite(res["return"])


