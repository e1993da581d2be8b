import re

import numpy as np
import pytest

from d5rl.datasets.dataset import ChunkedArray, Dataset
from d5rl.datasets.episode import Episode
from d5rl.datasets.loading import load_dataset
from tests.datasets.toy import register_toy


def make_ds(lengths=(3, 5, 2), terminal=(True, False, True), pixels=False):
    eps = []
    for e, (t, term) in enumerate(zip(lengths, terminal)):
        obs = (100 * e + np.arange(t + 1, dtype=np.float32))[:, None]
        arrays = {
            "actions": np.zeros((t, 1), np.float32),
            "rewards": (np.arange(t, dtype=np.float32) + 1) * (e + 1),
            "terminals": np.zeros(t, bool),
            "timeouts": np.zeros(t, bool),
        }
        if pixels:
            arrays["observations/pixels"] = np.broadcast_to(obs[:, :, None, None], (t + 1, 2, 2, 1)).astype(np.uint8)
            arrays["observations/proprio"] = obs
        else:
            arrays["observations"] = obs
        arrays["terminals"][-1] = term
        arrays["timeouts"][-1] = not term
        eps.append(Episode(arrays, {"e": e}))
    return Dataset.from_episodes(eps)


def test_chunked_array_indexing_matches_numpy():
    rng = np.random.default_rng(0)
    parts = [rng.normal(size=(n, 2, 3)) for n in (4, 1, 7, 3)]
    full = np.concatenate(parts)
    ca = ChunkedArray(parts)
    assert ca.shape == full.shape and len(ca) == len(full)
    for i in (0, 3, 4, 5, 14, -1):
        np.testing.assert_array_equal(ca[i], full[i])
    for sl in (slice(0, 15), slice(2, 9), slice(4, 5), slice(6, 6), slice(1, 14, 3)):
        np.testing.assert_array_equal(ca[sl], full[sl])
    idx = rng.integers(0, 15, size=(5, 4))
    np.testing.assert_array_equal(ca[idx], full[idx])
    np.testing.assert_array_equal(np.asarray(ca), full)
    with pytest.raises(IndexError):
        ca[np.array([15])]


def test_next_observations_follow_episode_boundaries():
    ds = make_ds()
    obs, nxt = ds.observations[:, 0], ds.next_observations[:, 0]
    np.testing.assert_array_equal(obs, [0, 1, 2, 100, 101, 102, 103, 104, 200, 201])
    np.testing.assert_array_equal(nxt, obs + 1)  # includes each episode's final observation
    b = ds.sample(64, np.random.default_rng(1))
    np.testing.assert_array_equal(b["next_observations"], b["observations"] + 1)
    np.testing.assert_array_equal(b["masks"], 1 - b["terminals"])


def test_mc_returns_brute_force():
    """Reward-to-go; an episode cut by its time limit (the second: not terminal) continues with its last reward
    forever, r_T / (1 − γ) (the D5RL release's tail), one that ends in a terminal state does not."""
    ds = make_ds()
    g = 0.9
    want = []
    for e, (t, term) in enumerate(zip((3, 5, 2), (True, False, True))):
        r = list((np.arange(t) + 1.0) * (e + 1)) + ([] if term else [(e + 1.0) * t] * 2000)  # γ^2000 ≈ 0
        want += [sum(g**k * r[j + k] for k in range(len(r) - j)) for j in range(t)]
    assert want[7] == pytest.approx(10.0 / (1 - g))  # the cut episode's last step: r_T / (1 − γ)
    np.testing.assert_allclose(ds.mc_returns(g), want, rtol=1e-6)
    b = ds.sample(8, np.random.default_rng(0), mc_gamma=g, indices=np.arange(8))
    np.testing.assert_allclose(b["mc_returns"], want[:8], rtol=1e-6)


def test_n_step_returns_stop_at_episode_end_and_terminals():
    ds = make_ds()
    g = 0.5
    b = ds.sample(10, np.random.default_rng(0), n_step=3, gamma=g, indices=np.arange(10))
    # transition 0 of episode 0 (rewards 1,2,3): 1 + .5*2 + .25*3, next obs = step 3, terminal -> discount 0
    assert b["rewards"][0] == pytest.approx(1 + 0.5 * 2 + 0.25 * 3)
    assert b["next_observations"][0, 0] == 3 and b["discounts"][0] == 0
    # transition 1: rewards 2,3 then the episode ends (terminal)
    assert b["rewards"][1] == pytest.approx(2 + 0.5 * 3) and b["discounts"][1] == 0
    # episode 1 (timeout, rewards 2,4,6,8,10): transition 3 -> 2 + 1*... steps 0..2
    assert b["rewards"][3] == pytest.approx(2 + 0.5 * 4 + 0.25 * 6)
    assert b["next_observations"][3, 0] == 103 and b["discounts"][3] == pytest.approx(0.125)
    # last transition of the timed-out episode: one reward, bootstrap from its final observation
    assert b["rewards"][7] == pytest.approx(10) and b["next_observations"][7, 0] == 105
    assert b["discounts"][7] == pytest.approx(0.5)


def test_frame_stack_clamps_at_episode_start():
    ds = make_ds(pixels=True)
    b = ds.sample(10, np.random.default_rng(0), frame_stack=3, indices=np.arange(10))
    px = b["observations"]["pixels"]
    assert px.shape == (10, 2, 2, 3)
    np.testing.assert_array_equal(px[0, 0, 0], [0, 0, 0])  # first step: repeated
    np.testing.assert_array_equal(px[2, 0, 0], [0, 1, 2])
    np.testing.assert_array_equal(px[3, 0, 0], [100, 100, 100])  # new episode: no leak from the last
    np.testing.assert_array_equal(b["next_observations"]["pixels"][3, 0, 0], [100, 100, 101])
    assert b["observations"]["proprio"].shape == (10, 1)


def test_to_d4rl_and_episode_iteration():
    ds = make_ds()
    d = ds.to_d4rl()
    assert set(d) >= {"observations", "next_observations", "actions", "rewards", "terminals", "timeouts"}
    assert all(len(v) == 10 for v in d.values())
    eps = list(ds.episodes())
    assert [e.num_transitions for e in eps] == [3, 5, 2] and eps[1].meta == {"e": 1}


def test_obs_keys_selects_parts():
    spec = register_toy("keys", num_episodes=4, pixels=True)
    ds = load_dataset(spec, obs_keys=["proprio"], progress=False)
    assert isinstance(ds.observations, np.ndarray) is False
    assert set(ds.observations) == {"proprio"}
    with pytest.raises(KeyError, match="no"):
        load_dataset(spec, obs_keys=["depth"], progress=False)


def test_next_actions_stay_within_the_episode():
    from d5rl.production.toy.data import toy_dataset

    ds = toy_dataset(3)
    last = ds.episode_starts + ds.episode_lengths - 1
    idx = np.array([0, int(last[0]), int(last[0]) + 1, int(last[2])])
    b = ds.sample(4, np.random.default_rng(0), next_actions=True, indices=idx)
    acts = np.asarray(ds.actions)
    np.testing.assert_array_equal(b["next_actions"], acts[[1, last[0], last[0] + 2, last[2]]])


def test_a_misspelt_dataset_argument_is_refused_before_generating():
    from d5rl.datasets.generation import dataset_root
    from d5rl.errors import DatasetArgumentError

    spec = register_toy("kwargs", num_episodes=4, per_shard=2)
    with pytest.raises(DatasetArgumentError, match=r"takes no argument 'episods' .*did you mean 'episodes'") as e:
        load_dataset(spec, episods=2, progress=False)
    assert isinstance(e.value, TypeError) and not dataset_root(spec.dataset).exists()  # nothing generated
    with pytest.raises(TypeError, match="did you mean 'cameras'.* cameras, size, render"):
        load_dataset("kitchen-standard-mixed-v0", camera=["wrist"], progress=False)


@pytest.mark.parametrize(
    "task, kwargs, needle",
    [
        (
            "kitchen-standard-mixed-v0",
            {"cameras": "wrist"},
            "cameras must be a list of distinct names from ['overview'",
        ),
        ("kitchen-randomized-demos-v0", {"cameras": ["overview"]}, "from ['left', 'right', 'wrist'], got ['overview']"),
        ("kitchen-randomized-demos-v0", {"cameras": ["left", "left"]}, "distinct"),
        ("wx-sorting-v0", {"size": 100_000}, "size must be an integer number of pixels from 8 to 1024, got 100000"),
        ("wx-sorting-v0", {"size": 0}, "got 0"),
    ],
)
def test_a_bad_render_argument_is_refused_before_any_work(task, kwargs, needle, monkeypatch):
    from d5rl.datasets import generation
    from d5rl.errors import DatasetArgumentError

    monkeypatch.setattr(generation, "generate", lambda *a, **k: pytest.fail("generated before checking"))
    with pytest.raises(DatasetArgumentError, match=re.escape(needle)) as e:
        load_dataset(task, episodes=1, progress=False, **kwargs)
    assert isinstance(e.value, ValueError)
