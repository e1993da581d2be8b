"""Standard kitchen data: demonstrator success, generator determinism, dataset round trip,
relabelling, rendered frames from stored states, and the D4RL importer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import d5rl
from d5rl.cli import main
from d5rl.datasets.loading import load_dataset
from d5rl.envs.base import qpos_of_states
from d5rl.envs.kitchen.data import state_episode
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES, CompletionChecker
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.production.kitchen import data as kdata
from d5rl.production.kitchen.data import (
    COMBINATIONS,
    KitchenStandardGenerator,
    combination_schedule,
    habit_schedule,
    order_probabilities,
    relabel,
)


def test_combinations_never_contain_the_partial_task():
    assert len(COMBINATIONS) == 22 and len(set(COMBINATIONS)) == 22
    assert all(len(set(c)) == 4 and set(c) <= set(SUBTASK_NAMES) for c in COMBINATIONS)
    assert all(set(c) != set(PARTIAL) for c in COMBINATIONS)
    assert tuple(MIXED) in COMBINATIONS


def test_order_probabilities_follow_the_habit():
    p = dict(zip(COMBINATIONS, order_probabilities(0.8)))
    assert sum(p.values()) == pytest.approx(1.0)
    # the habitual branch at every choice: microwave (of 4 first subtasks), kettle (of microwave's 4
    # continuations), bottom burner (of 4), top burner (of 3)
    assert p[("microwave", "kettle", "bottom burner", "top burner")] == pytest.approx(0.8**4)
    # the mixed task's order: habitual, habitual, one of the 3 others after (microwave, kettle), habitual
    assert p[tuple(MIXED)] == pytest.approx(0.8 * 0.8 * 0.2 / 3 * 0.8)
    # the top burner first (one of the 3 other first subtasks) has a single continuation
    assert p[("top burner", "light switch", "slide cabinet", "hinge cabinet")] == pytest.approx(0.2 / 3)
    assert min(order_probabilities(0.8)) > 0  # every combination stays in the data


def test_combination_schedule_keeps_every_prefix_in_proportion():
    probs = order_probabilities(0.8)
    full = combination_schedule(probs, 563)
    assert combination_schedule(probs, 100) == full[:100]  # episode i's combination does not depend on n
    for n in (22, 100, 563):
        counts = np.bincount(full[:n], minlength=len(COMBINATIONS))
        assert np.all(np.abs(counts - n * np.asarray(probs)) < 1.0), n
    assert habit_schedule(0.8, 563)[:563] == tuple(full)
    # a generator with a habit performs the scheduled combinations; without one, round-robin
    gen = KitchenStandardGenerator(max_steps=2, habit=0.8)
    assert [gen.episode(i, np.random.default_rng(i)).meta["combination"] for i in range(3)] == full[:3]
    assert KitchenStandardGenerator(max_steps=2).episode(23, np.random.default_rng(0)).meta["combination"] == 1
    assert sorted(set(full)) == list(range(len(COMBINATIONS)))  # every combination appears


def test_generator_is_a_pure_function_of_index_and_rng():
    gen = KitchenStandardGenerator(max_steps=60)
    a = gen.episode(5, np.random.default_rng([0, 5]))
    gen.episode(1, np.random.default_rng([0, 1]))  # another episode in between changes nothing
    b = KitchenStandardGenerator(max_steps=60).episode(5, np.random.default_rng([0, 5]))
    c = gen.episode(5, np.random.default_rng([1, 5]))
    a.validate()
    assert a.meta == b.meta and a.meta["subtasks"] == list(COMBINATIONS[5])
    for k in a.arrays:
        assert a.arrays[k].tobytes() == b.arrays[k].tobytes(), k
    assert a.arrays["actions"].tobytes() != c.arrays["actions"].tobytes()


def test_dataset_round_trip_relabel_and_renders(monkeypatch, tmp_path):
    ds = load_dataset("kitchen-standard-mixed-v0", episodes=2, workers=1, progress=False, render=False)
    assert ds.num_episodes == 2 and ds.episode_meta[0]["subtasks"] == list(COMBINATIONS[0])
    assert ds.arrays["states"].shape[0] == ds.num_transitions + 2
    # stored completion flags agree with the stored states (qpos follows the time entry)
    env = KitchenEnv(obs_mode="state")
    checker = CompletionChecker(env.model)
    step_done = checker.completed(qpos_of_states(ds.arrays["states"], env.model.nq))
    next_rows = ds.transition_step + 1
    np.testing.assert_array_equal(step_done[next_rows], ds.arrays["infos/completed"])
    np.testing.assert_array_equal(
        np.asarray(ds.arrays["observations/proprio"]), qpos_of_states(ds.arrays["states"], 9).astype(np.float32)
    )
    # the -state tasks' observations, read from the stored states without simulating, are the env's
    observed = state_episode({"states": ds.arrays["states"]}, {})["observations"]
    for row in (0, 60, len(observed) - 1):
        env.set_state(ds.arrays["states"][row])
        np.testing.assert_array_equal(observed[row], env._get_obs())
    # each task counts its own subtasks
    done = ds.arrays["infos/completed"]
    for task, tasks in (("kitchen-standard-mixed-v0", MIXED), ("kitchen-standard-partial-v0", PARTIAL)):
        spec = d5rl.get_spec(task)
        r = relabel(spec, ds.arrays)["rewards"]
        cols = [SUBTASK_NAMES.index(t) for t in tasks]
        np.testing.assert_array_equal(r, done[:, cols].sum(1))
    # a -state task with render=False: states only, no cache built (what `d5rl render --episode` reads)
    twin = load_dataset("kitchen-standard-mixed-state-v0", episodes=2, progress=False, render=False)
    np.testing.assert_array_equal(twin.arrays["states"], ds.arrays["states"])
    assert "observations" not in twin.arrays and not (Path(twin.metadata["root"]) / "renders" / "state").exists()
    assert (
        main(
            [
                "render",
                "kitchen-standard-mixed-state-v0",
                "--episode",
                "1",
                "--steps",
                "2",
                "--size",
                "16x16",
                "--out",
                str(tmp_path / "ep.mp4"),
                "--no-progress",
            ]
        )
        == 0
    )
    partial = load_dataset("kitchen-standard-partial-v0", episodes=2, workers=1, progress=False, render=False)
    assert not np.array_equal(partial.rewards, ds.rewards)
    assert partial.rewards.max() <= 3  # never all four partial subtasks in one episode
    # camera frames come from the stored states; re-rendering never runs the demonstrator
    import d5rl.production.kitchen.demonstrator as dm

    monkeypatch.setattr(kdata.KitchenStandardGenerator, "episode", lambda *a: (_ for _ in ()).throw(AssertionError))

    monkeypatch.setattr(dm.Demonstrator, "act", lambda self: (_ for _ in ()).throw(AssertionError("demonstrator ran")))
    pix = load_dataset("kitchen-standard-mixed-v0", episodes=1, workers=1, progress=False, size=16)
    frames = pix.arrays["observations/pixels/overview"]
    assert frames.shape == (pix.num_transitions + 1, 16, 16, 3) and frames.dtype == np.uint8
    env16 = KitchenEnv(image_size=16)
    env16.set_state(np.asarray(pix.arrays["states"][7]))
    np.testing.assert_array_equal(env16.render_cameras()["wrist"], pix.arrays["observations/pixels/wrist"][7])
    batch = pix.sample(4, np.random.default_rng(0), frame_stack=3)
    assert batch["observations"]["pixels/overview"].shape == (4, 16, 16, 9)


def test_imported_human_data_render_for_the_camera_tasks(tmp_path):
    """A tiny D4RL-layout file imported with its camera frames: the camera task's dataset is the imported
    states rendered (the importer itself: test_kitchen_human.py)."""
    h5py = pytest.importorskip("h5py")
    from d5rl.envs.kitchen import model as km

    rng = np.random.default_rng(0)
    n = 9  # two episodes: rows 0-4 and 5-8
    qpos = np.tile(km.INIT_QPOS, (n, 1)) + rng.normal(0, 0.01, (n, 30)) * np.r_[np.ones(9), np.zeros(21)]
    qpos[3:5, 22] = -0.75  # microwave open at the end of episode 0
    obs = np.concatenate([qpos, np.zeros((n, 30))], axis=1).astype(np.float32)
    terminals = np.zeros(n, bool)
    terminals[4] = True
    path = tmp_path / "kitchen_mixed-v0.hdf5"
    with h5py.File(path, "w") as f:
        f["observations"] = obs
        f["actions"] = rng.uniform(-1, 1, (n, 9)).astype(np.float32)
        f["rewards"] = np.zeros(n, np.float32)
        f["terminals"] = terminals
        f["timeouts"] = np.zeros(n, bool)
    assert main(["import-kitchen-human", str(path), "--size", "16", "--workers", "1", "--no-progress"]) == 0
    ds = load_dataset("kitchen-standard-mixed-human-v0", size=16, progress=False, workers=1)
    assert ds.num_episodes == 2 and list(ds.episode_lengths) == [4, 3]
    np.testing.assert_allclose(ds.arrays["observations/proprio"], obs[:, :9])
    frames = ds.arrays["observations/pixels/overview"]
    assert frames.shape == (n, 16, 16, 3)
    env16 = KitchenEnv(image_size=16)
    env16.set_state(np.asarray(ds.arrays["states"][3]))
    np.testing.assert_array_equal(env16.render_cameras()["overview"], frames[3])
    np.testing.assert_array_equal(ds.rewards[:4], [0, 0, 1, 1])  # microwave (a mixed subtask) from row 3 on
