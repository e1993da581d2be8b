"""The WidowX scripted datasets: plans, success rates, purity, generate and load."""

from __future__ import annotations

import numpy as np
import pytest

from d5rl.envs.widowx.data import render_states
from d5rl.production.widowx.data import WidowXScriptedGenerator


def test_scripted_grasp_success_band():
    """Objects lie on any side; the scripted pick-and-place still works for most of them
    (docs/datacards/widowx.md: ~90% of real grasps end in the intended bin over 2,000 episodes)."""
    gen = WidowXScriptedGenerator(mode="sorting", p_wrong=0.0)
    eps = [gen.episode(i, np.random.default_rng([7, i])) for i in range(8)]
    placed = [ok for e in eps for ok in e.meta["placed_as_intended"]]
    assert np.mean(placed) >= 0.75
    for e in eps:  # both sorted: stage 1 succeeded before stage 2, in time
        if e.meta["num_sorted"] == 2:
            assert e.meta["policy_done_step"] is not None and e.meta["policy_done_step"] < 100
            assert e.arrays["rewards"][-1] == 2


def test_sorting_plans():
    """ "one" attempts the first object only; "miss" closes the gripper above one object, which stays put."""
    one = WidowXScriptedGenerator(mode="sorting", p_wrong=0.0, p_one=1.0).episode(0, np.random.default_rng([5, 0]))
    assert one.meta["plan"] == "one" and len(one.meta["objects"]) == 1 and one.meta["num_sorted"] <= 1
    miss = WidowXScriptedGenerator(mode="sorting", p_wrong=0.0, p_miss=1.0).episode(0, np.random.default_rng([5, 0]))
    assert miss.meta["plan"] == "miss" and sum(miss.meta["missed_grasp"]) == 1
    k = miss.meta["missed_grasp"].index(True)
    assert not miss.meta["lifted"][k] and miss.meta["final_bins"][k] is None
    with pytest.raises(ValueError, match="p_one"):
        WidowXScriptedGenerator(mode="pickplace", p_one=0.5)


def test_sorting_data_profile():
    """The paper's profile: the whole task mostly unsolved, each segment solved often (16 episodes of the
    registered mix; all 2,000 are measured in docs/datacards/widowx.md)."""
    from d5rl.datasets.generation import make_generator

    gen = make_generator("wx-sorting-v0")
    metas = [gen.episode(i, np.random.default_rng([9, i])).meta for i in range(16)]
    assert np.mean([m["num_sorted"] == 2 for m in metas]) < 0.5
    for cat in ("shoe", "toy"):
        assert np.mean([m["end_bins"][cat] == cat for m in metas]) >= 0.2, cat
    assert {m["plan"] for m in metas} == {"both", "one", "miss"}


def test_wrong_bin_choice_rate():
    gen = WidowXScriptedGenerator(mode="pickplace")
    wrong = [gen.episode(i, np.random.default_rng([3, i])).meta["wrong_bin"][0] for i in range(12)]
    assert 0 < sum(wrong) < 12  # both outcomes occur (p = 0.3)


def test_generator_is_pure_function_of_index_and_rng():
    a = WidowXScriptedGenerator(mode="pickplace", episode_steps=20)
    b = WidowXScriptedGenerator(mode="pickplace", episode_steps=20)
    a.episode(5, np.random.default_rng([0, 5]))  # different history
    e1 = a.episode(1, np.random.default_rng([0, 1]))
    e2 = b.episode(1, np.random.default_rng([0, 1]))
    e1.validate()
    for k in e1.arrays:
        assert np.array_equal(e1.arrays[k], e2.arrays[k]), k
    assert e1.meta == e2.meta


def test_generate_and_load_round_trip():
    from d5rl.datasets.loading import load_dataset

    ds = load_dataset("wx-sorting-pickplacedata-v0", episodes=3, workers=1, progress=False)
    assert ds.num_episodes == 3 and ds.num_transitions == 3 * 60
    assert ds.arrays["observations/proprio"].shape == (3 * 61, 8)
    assert ds.arrays["states"].shape[0] == 3 * 61
    assert set(ds.episode_meta[0]) >= {"domain", "objects", "target_bins", "final_bins", "num_sorted"}
    # camera frames come from the render cache, re-rendered from the stored states
    pix = ds.arrays["observations/pixels/side"]
    assert pix.shape == (3 * 61, 128, 128, 3) and pix.dtype == np.uint8
    first_of_ep2 = 61
    frames = render_states(ds.arrays["states"][first_of_ep2 : first_of_ep2 + 2], ds.episode_meta[1])
    np.testing.assert_array_equal(frames, pix[first_of_ep2 : first_of_ep2 + 2])
    batch = ds.sample(4, np.random.default_rng(0))
    assert batch["observations"]["pixels/side"].shape == (4, 128, 128, 3)
    small = load_dataset("wx-sorting-pickplacedata-v0", episodes=3, workers=1, progress=False, size=32)
    assert small.arrays["observations/pixels/side"].shape == (3 * 61, 32, 32, 3)
    # rewards agree with the stored outcome
    ends = np.cumsum(ds.episode_lengths) - 1
    assert [int(ds.rewards[e]) for e in ends] == [m["num_sorted"] for m in ds.episode_meta]
