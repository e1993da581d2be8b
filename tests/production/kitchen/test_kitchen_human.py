"""The human kitchen data: `d5rl import-kitchen-human` on fixtures in Minari's and D4RL's layouts, built
from our own scripted episodes, then the imported data as the `-human-v0` tasks' dataset everywhere.

Fixture layouts follow the formats' generation code: Minari's ``D4RL/kitchen/*-v2`` come from
``scripts/D4RL/kitchen/create_franka_dataset.py`` (Farama-Foundation/minari-dataset-generation-scripts)
recording gymnasium-robotics' ``FrankaKitchen-v1`` (``gymnasium_robotics/envs/franka_kitchen/kitchen_env.py``:
the 59-D ``observation``, ``achieved_goal``/``desired_goal`` per target subtask) with Minari's HDF5 storage
(``minari/dataset/_storages/hdf5_storage.py``: ``episode_<i>`` groups); D4RL's kitchen files come from
``scripts/generation/generate_kitchen_datasets.py`` (Farama-Foundation/D4RL): 60-D float32 observations
(30 joint positions, the task's 30-D goal), ``terminals`` (float32) true on each demonstration's last row,
no ``timeouts``, ``infos`` the demonstration's index.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import d5rl
from d5rl.cli import main
from d5rl.datasets.loading import load_dataset
from d5rl.envs.base import qpos_of_states
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES, SUBTASKS, THRESHOLD
from d5rl.errors import D5RLError

h5py = pytest.importorskip("h5py")

# the target subtasks of Minari's D4RL/kitchen/mixed-v2 and D4RL's kitchen_mixed-v0 (GOAL_TASKS['mixed'])
FILE_TASKS = ("microwave", "kettle", "bottom burner", "light switch")
COMBOS = (0, 13)  # microwave first, kettle first
TASK = "kitchen-standard-mixed-state-human-v0"


@pytest.fixture(scope="module")
def scripted():
    """Two scripted episodes: (qpos (T+1, 30), qvel (T+1, 29), actions (T, 9), completed (T, 7))."""
    from d5rl.envs.kitchen import model as km
    from d5rl.production.kitchen.data import KitchenStandardGenerator

    gen = KitchenStandardGenerator(max_steps=120)
    out = []
    for i in COMBOS:
        ep = gen.episode(i, np.random.default_rng([0, i]))
        states = ep.arrays["states"]
        nq = km.NUM_ROBOT_QPOS + km.NUM_OBJECT_QPOS
        out.append(
            (
                qpos_of_states(states, nq),
                states[:, 1 + nq : 1 + nq + nq - 1],
                ep.arrays["actions"],
                ep.arrays["infos/completed"],
            )
        )
    return out


def _indices():
    from d5rl.envs.kitchen import model as km

    m = km.build_model()
    return {t: SUBTASKS[t].qpos_indices(m) for t in SUBTASK_NAMES}


def write_minari(root, episodes, noise=1e-3, dataset_id="D4RL/kitchen/mixed-v2", desired_shift=None):
    """A Minari dataset directory ``<root>/<dataset_id>/data/{main_data.hdf5,metadata.json}``."""
    import gymnasium as gym
    from minari.serialization import serialize_space

    idx = _indices()
    data = root / dataset_id / "data"
    data.mkdir(parents=True)
    rng = np.random.default_rng(0)
    with h5py.File(data / "main_data.hdf5", "w") as f:
        for e, (qpos, qvel, actions, _) in enumerate(episodes):
            g = f.create_group(f"episode_{e}")
            g.attrs.update({"id": e, "total_steps": len(actions)})
            # gymnasium-robotics adds uniform noise to the observation (not to achieved_goal)
            noisy = qpos + rng.uniform(-noise, noise, qpos.shape)
            g["observations/observation"] = np.concatenate(
                [noisy[:, :9], qvel[:, :9], noisy[:, 9:], qvel[:, 9:]], axis=1
            )
            for t in FILE_TASKS:
                goal = np.array(SUBTASKS[t].goal) + (
                    desired_shift if desired_shift and e == 0 and t == "microwave" else 0.0
                )
                g[f"observations/achieved_goal/{t}"] = qpos[:, idx[t]]
                g[f"observations/desired_goal/{t}"] = np.tile(goal, (len(qpos), 1))
            g["actions"] = actions
            done = np.stack(
                [np.linalg.norm(qpos[1:, idx[t]] - SUBTASKS[t].goal, axis=-1) < THRESHOLD for t in FILE_TASKS], axis=1
            )
            g["rewards"] = done.sum(axis=1).astype(np.float64)
            g["terminations"] = np.zeros(len(actions), bool)
            g["truncations"] = np.eye(1, len(actions), len(actions) - 1, dtype=bool)[0]
            g["infos/ctrl"] = np.zeros((len(qpos), 9))  # create_franka_dataset.py's step callback
    boxes = {t: gym.spaces.Box(-np.inf, np.inf, (len(idx[t]),), np.float64) for t in FILE_TASKS}
    obs_space = gym.spaces.Dict(
        {
            "achieved_goal": gym.spaces.Dict(boxes),
            "desired_goal": gym.spaces.Dict(boxes),
            "observation": gym.spaces.Box(-np.inf, np.inf, (59,), np.float64),
        }
    )
    meta = {
        "dataset_id": dataset_id,
        "total_episodes": len(episodes),
        "data_format": "hdf5",
        "total_steps": int(sum(len(a) for _, _, a, _ in episodes)),
        "minari_version": "0.5.0",
        "observation_space": serialize_space(obs_space),
        "action_space": serialize_space(gym.spaces.Box(-1.0, 1.0, (9,), np.float32)),
    }
    (data / "metadata.json").write_text(json.dumps(meta))
    return root / dataset_id


def write_d4rl(path, episodes):
    """A D4RL kitchen file: rows of all episodes back to back, the last row of each a terminal."""
    idx = _indices()
    goal = np.zeros(30)
    for t in FILE_TASKS:
        goal[idx[t]] = SUBTASKS[t].goal
    obs, acts, timeouts = [], [], []
    for qpos, _, actions, _ in episodes:
        obs.append(np.concatenate([qpos, np.tile(goal, (len(qpos), 1))], axis=1))
        acts.append(np.concatenate([actions, np.zeros((1, 9), np.float32)]))  # the last row's action is unused
        timeouts.append(np.eye(1, len(qpos), len(qpos) - 1, dtype=bool)[0])
    with h5py.File(path, "w") as f:
        f["observations"] = np.concatenate(obs).astype(np.float32)
        f["actions"] = np.concatenate(acts)
        f["rewards"] = np.zeros(len(f["observations"]), np.float32)
        f["terminals"] = np.concatenate(timeouts).astype(np.float32)
        f["infos"] = np.concatenate([np.full(len(q), i) for i, (q, *_) in enumerate(episodes)])
    return path


def test_the_minari_fixture_is_what_minari_reads(tmp_path, scripted):
    from minari.dataset.minari_storage import MinariStorage

    root = write_minari(tmp_path / "minari", scripted)
    storage = MinariStorage.read(root / "data")
    ep = next(iter(storage.get_episodes([1])))
    assert storage.total_episodes == 2
    assert ep["observations"]["observation"].shape == (len(scripted[1][0]), 59)
    np.testing.assert_array_equal(ep["observations"]["achieved_goal"]["kettle"], scripted[1][0][:, 23:30])
    np.testing.assert_array_equal(ep["actions"], scripted[1][2])


def test_import_a_minari_dataset_found_through_minari_datasets_path(tmp_path, monkeypatch, scripted, capsys):
    write_minari(tmp_path / "minari", scripted)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    assert main(["import-kitchen-human", "D4RL/kitchen/mixed-v2", "--no-render", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "replay check: 2 of 2 episodes agree" in out and "action check: one step of our env" in out
    ds = load_dataset(TASK, progress=False)
    assert ds.num_episodes == 2 and list(ds.episode_lengths) == [len(a) for _, _, a, _ in scripted]
    states = np.asarray(ds.arrays["states"])
    starts = np.r_[0, np.cumsum(ds.episode_lengths + 1)]
    for e, (qpos, qvel, _actions, _completed) in enumerate(scripted):
        s = states[starts[e] : starts[e + 1]]
        # the target subtasks' joints come from the noise-free achieved_goal, the rest from the noisy observation
        exact = np.concatenate([_indices()[t] for t in FILE_TASKS])
        np.testing.assert_array_equal(s[:, 1 + exact], qpos[:, exact])
        np.testing.assert_allclose(s[:, 1:31], qpos, atol=1e-3)
        np.testing.assert_array_equal(s[:, 31:60], qvel)  # velocities restored
    np.testing.assert_array_equal(ds.arrays["actions"], np.concatenate([a for _, _, a, _ in scripted]))
    # every subtask is where the scripted episode left it (the noise is far below the 0.3 threshold)
    np.testing.assert_array_equal(ds.arrays["infos/completed"], np.concatenate([c for *_, c in scripted]))
    # rewards: the mixed task's four subtasks; the observation: 30 joint positions from the states
    cols = [SUBTASK_NAMES.index(t) for t in MIXED]
    np.testing.assert_array_equal(ds.rewards, np.concatenate([c for *_, c in scripted])[:, cols].sum(axis=1))
    np.testing.assert_allclose(ds.arrays["observations"], states[:, 1:31].astype(np.float32))
    partial = load_dataset("kitchen-standard-partial-state-human-v0", progress=False)
    cols = [SUBTASK_NAMES.index(t) for t in PARTIAL]
    np.testing.assert_array_equal(partial.rewards, np.concatenate([c for *_, c in scripted])[:, cols].sum(axis=1))
    manifest = json.loads((tmp_path / "d5rl-home/datasets/kitchen-standard-human/v1-seed0/manifest.json").read_text())
    assert manifest["source"]["id"] == "D4RL/kitchen/mixed-v2" and manifest["source"]["layout"] == "minari"
    assert manifest["replay_check"]["episodes_mismatched"] == 0
    assert ds.episode_meta[0]["subtasks"][0] == "microwave" and ds.episode_meta[1]["subtasks"][0] == "kettle"


def test_import_a_d4rl_file_then_train_bc_through_d5rl_train(tmp_path, scripted):
    path = write_d4rl(tmp_path / "kitchen_mixed-v0.hdf5", scripted)
    assert main(["import-kitchen-human", str(path), "--no-render", "--no-progress"]) == 0
    ds = load_dataset(TASK, progress=False)
    assert ds.num_episodes == 2
    np.testing.assert_allclose(
        qpos_of_states(ds.arrays["states"], 30), np.concatenate([q for q, *_ in scripted]).astype(np.float32), atol=0
    )
    assert not np.asarray(ds.arrays["states"])[:, 31:60].any()  # D4RL stores no velocities
    np.testing.assert_array_equal(ds.arrays["infos/completed"], np.concatenate([c for *_, c in scripted]))
    _train_bc(tmp_path)


def test_verify_render_and_seeds_on_imported_data(tmp_path, scripted, capsys):
    from d5rl.datasets.generation import dataset_root
    from tests.test_bad_input import one_line_error

    assert (
        main(["import-kitchen-human", str(write_d4rl(tmp_path / "k.hdf5", scripted)), "--no-render", "--no-progress"])
        == 0
    )
    assert main(["verify", TASK]) == 0
    video = tmp_path / "ep.gif"
    assert (
        main(
            [
                "render",
                "kitchen-standard-mixed-human-v0",
                "--episode",
                "1",
                "--steps",
                "2",
                "--out",
                str(video),
                "--no-progress",
            ]
        )
        == 0
        and video.stat().st_size > 0
    )
    one_line_error(
        capsys, ["render", TASK, "--episode", "2", "--out", str(video)], "has no episode 2", "numbered 0 to 1"
    )
    with pytest.raises(D5RLError, match="imported and has no seed"):
        load_dataset(TASK, seed=3)
    shard = next((dataset_root(d5rl.get_spec(TASK).dataset) / "shards").iterdir())
    (shard / "actions.npy").write_bytes(b"damaged")
    capsys.readouterr()
    assert main(["verify", TASK]) == 1
    assert "fix: `d5rl import-kitchen-human D4RL/kitchen/mixed-v2` imports the data again" in capsys.readouterr().err
    with pytest.raises(D5RLError, match="damaged shard") as e:
        load_dataset(TASK)  # never "regenerated": the hint is the import
    assert "d5rl import-kitchen-human" in e.value.hint


def _train_bc(tmp_path):
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "bc",
                TASK,
                "--offline-steps",
                "16",
                "--run-dir",
                str(run),
                "--no-progress",
                "--set",
                "hidden_dims=16,16",
                "--set",
                "batch_size=8",
                "--set",
                "eval_episodes=1",
                "--set",
                "eval_envs=1",
                "--set",
                "tensorboard=false",
                "--set",
                "checkpoint_interval=16",
            ]
        )
        == 0
    )
    config = json.loads((run / "config.json").read_text())
    assert config["dataset"]["dataset"] == "kitchen-standard-human"
    assert (run / "checkpoint").exists() or any(run.glob("checkpoint*"))


def test_train_bc_on_an_imported_minari_dataset(tmp_path, monkeypatch, scripted):
    # seconds after the D4RL one (the session's JAX compilation cache); ~20 s alone
    root = write_minari(tmp_path / "minari", scripted)
    assert main(["import-kitchen-human", str(root), "--no-render", "--no-progress"]) == 0
    _train_bc(tmp_path)


@pytest.mark.parametrize("sign", [1, -1])
def test_action_check_measures_whether_the_actions_move_our_robot(tmp_path, scripted, sign):
    """Noise-free positions and velocities with the scripted actions: one env step from each stored state lands
    on the next one; with the actions negated it misses by about two steps' motion."""
    flipped = [(q, v, sign * a, c) for q, v, a, c in scripted]
    assert (
        main(
            [
                "import-kitchen-human",
                str(write_minari(tmp_path / "m", flipped, noise=0.0)),
                "--no-render",
                "--no-progress",
            ]
        )
        == 0
    )
    manifest = json.loads((tmp_path / "d5rl-home/datasets/kitchen-standard-human/v1-seed0/manifest.json").read_text())
    check = manifest["replay_check"]["actions"]
    assert check["transitions"] == sum(len(range(0, len(a), 10)) for _, _, a, _ in scripted)
    if sign == 1:
        assert check["median_rad"] < 1e-6
    else:
        assert check["median_rad"] > check["median_step_rad"]


def test_a_minari_id_is_found_under_home_without_minari_datasets_path(tmp_path, monkeypatch, scripted):
    from d5rl.production.kitchen.human import locate

    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    root = write_minari(tmp_path / ".minari" / "datasets", scripted[:1])
    assert locate("D4RL/kitchen/mixed-v2") == ("minari", root / "data" / "main_data.hdf5")
    assert locate(root) == locate(root / "data") == locate(root / "data" / "main_data.hdf5")
    path = write_d4rl(tmp_path / "kitchen_mixed-v0.hdf5", scripted[:1])
    assert locate(path) == ("d4rl", path)


def test_replay_mismatches_are_reported_per_episode(tmp_path, scripted, capsys):
    # the file's goal for the microwave moved far away: the file says never done, our scene says done
    root = write_minari(tmp_path / "minari", scripted, desired_shift=5.0)
    assert main(["import-kitchen-human", str(root / "data" / "main_data.hdf5"), "--no-render", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "replay check: 1 of 2 episodes agree" in out
    assert "episode 0: file says done ['kettle'], our scene ['kettle', 'microwave']" in out
    n = int(scripted[0][3][:, SUBTASK_NAMES.index("microwave")].sum())
    assert f"steps that differ: {{'microwave': {n}}}" in out


def test_missing_import_names_the_commands(tmp_path, capsys):
    with pytest.raises(D5RLError, match="not in .*kitchen-standard-human") as e:
        d5rl.make(TASK)
    assert "minari download D4RL/kitchen/mixed-v2" in e.value.hint
    assert "d5rl import-kitchen-human D4RL/kitchen/mixed-v2" in e.value.hint
    from tests.test_bad_input import one_line_error

    one_line_error(
        capsys,
        ["train", "bc", TASK, "--offline-steps", "8", "--run-dir", str(tmp_path / "r")],
        "minari download D4RL/kitchen/mixed-v2",
        "d5rl import-kitchen-human",
    )
    one_line_error(capsys, ["generate", TASK], "is imported, not generated", "d5rl import-kitchen-human")
    one_line_error(
        capsys, ["import-kitchen-human", "D4RL/kitchen/nothing-v2"], "no kitchen dataset at", "minari download"
    )


def test_human_tasks_are_variants_of_the_standard_tasks():
    from d5rl.registry import base_task, variant_id
    from d5rl.runner.cli import resolve_tasks
    from d5rl.runner.paper import paper_task

    assert variant_id("kitchen-standard-mixed-state-v0", "human") == TASK
    spec, base = d5rl.get_spec(TASK), d5rl.get_spec("kitchen-standard-mixed-state-v0")
    assert base_task(TASK) == base.id and spec.variant == "human"
    assert (spec.env_kwargs, spec.relabel, spec.group, spec.observation) == (
        base.env_kwargs,
        base.relabel,
        base.group,
        base.observation,
    )
    assert spec.dataset.imported and spec.dataset.name == "kitchen-standard-human"
    assert paper_task(TASK) == "kitchen-standard-mixed-v0"  # the paper trained on these data
    # a group stands for the scripted-data tasks; the human ones when named
    assert not any("human" in t for t in resolve_tasks(["kitchen-standard"]))
    assert resolve_tasks(["kitchen-standard-mixed-human"]) == ["kitchen-standard-mixed-human-v0"]
    assert "kitchen-standard-mixed-state-human-v0" in resolve_tasks(["kitchen-standard-*-human-v0"])


def test_comparison_statistics_of_the_imported_data(tmp_path, monkeypatch, scripted, capsys):
    from d5rl.browse.catalog import task_summary
    from d5rl.production.kitchen.datacard import comparison_stats, print_comparison

    root = write_minari(tmp_path / "minari", scripted)
    assert main(["import-kitchen-human", str(root), "--no-render", "--no-progress"]) == 0
    capsys.readouterr()
    summary = task_summary(TASK)  # what `d5rl browse` lists
    assert summary["status"] == "ready" and summary["dataset"]["episodes"] == 2
    s = comparison_stats(TASK)
    lengths = [len(a) for _, _, a, _ in scripted]
    assert (s["episodes"], s["transitions"], s["length_min"], s["length_max"]) == (
        2,
        sum(lengths),
        min(lengths),
        max(lengths),
    )
    # orders: each subtask by the first step its column is true, computed here per subtask
    orders = []
    for *_, completed in scripted:
        firsts = {SUBTASK_NAMES[j]: np.flatnonzero(completed[:, j])[0] for j in range(7) if completed[:, j].any()}
        orders.append(tuple(sorted(firsts, key=firsts.get)))
    assert s["orders"] == len(set(orders)) and s["subtasks_mean"] == np.mean([len(o) for o in orders])
    assert s["first_subtask"] == {orders[0][0]: 0.5, orders[1][0]: 0.5}
    acts = [a.astype(np.float64) for _, _, a, _ in scripted]
    flat = np.concatenate(acts)
    assert s["action_abs_mean"] == pytest.approx(np.abs(flat).mean())
    assert s["action_saturated"] == pytest.approx((np.abs(flat) >= 0.99).mean())
    assert s["action_change_mean"] == pytest.approx(np.concatenate([np.abs(np.diff(a, axis=0)) for a in acts]).mean())
    print_comparison(s, None)
    table = capsys.readouterr().out
    assert f"| episode length mean (min-max) | {np.mean(lengths):.1f} ({min(lengths)}-{max(lengths)}) | - |" in table
