"""The A1 v1 data path, with stand-in published agents: random-weight actors in the snapshot format, in a
temporary policy directory named by ``D5RL_A1_POLICIES`` (what the trained agents' ``publish`` ships).

`d5rl generate`, `verify` and `calibrate` run in subprocesses that start with the variable (as a user
checking trained agents before publishing them would); this process reads the same files through specs
that point at them.
"""

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import d5rl
from d5rl.datasets.loading import load_dataset
from d5rl.envs.a1 import arenas, v1
from d5rl.envs.a1.published import buffer_episodes
from d5rl.envs.a1.registration import HIKING_AGENTS_V1, SPEED_AGENTS_V1
from d5rl.production.a1 import data as a1_data
from d5rl.production.a1.agents import AGENTS
from d5rl.production.a1.data import replay_env
from d5rl.production.a1.policy import SnapshotPolicy, save_actor
from d5rl.registry import make_env

REPO = Path(__file__).resolve().parents[3]
V1_AGENTS = [a for a, s in AGENTS.items() if s.env_version == 1]
# per data agent: uniform random actions, then two snapshots (the training log's segments)
SEGMENTS = [
    {"snapshot": None, "start_step": 0, "episodes": 2, "steps": 800},
    {"snapshot": "snapshot-01.npz", "start_step": 800, "episodes": 1, "steps": 400},
    {"snapshot": "snapshot-02.npz", "start_step": 1200, "episodes": 1, "steps": 400},
]


def _actor(rng: np.random.Generator, obs_dim: int, hidden=(32, 32)) -> dict:
    """A random actor in the flax layout that `save_actor` exports (MLP trunk, mean and log-std heads)."""
    tree, d = {"MLP_0": {}}, obs_dim
    for i, h in enumerate(hidden):
        tree["MLP_0"][f"Dense_{i}"] = {"kernel": rng.normal(0, 1 / np.sqrt(d), (d, h)), "bias": np.zeros(h)}
        d = h
    tree["Dense_0"] = {"kernel": rng.normal(0, 0.3, (d, 12)), "bias": np.zeros(12)}
    tree["Dense_1"] = {"kernel": np.zeros((d, 12)), "bias": np.full(12, -1.0)}
    return tree


@pytest.fixture(scope="module")
def policies(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("policies")
    rng = np.random.default_rng(0)
    for agent in V1_AGENTS:
        spec = AGENTS[agent]
        segments = SEGMENTS if spec.role == "data" else []
        for name in ["final.npz"] + [s["snapshot"] for s in segments if s["snapshot"]]:
            save_actor(_actor(rng, spec.obs_dim), root / agent / name)
        log = {"agent": agent, "target_speed": spec.target_speed, "steps": 1600, "segments": segments}
        (root / agent / "log.json").write_text(json.dumps(log))
    return root


def d5rl_cli(policies: Path, home: Path, *args: str) -> str:
    env = {
        **os.environ,
        "D5RL_A1_POLICIES": str(policies),
        "D5RL_HOME": str(home),
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    proc = subprocess.run(
        [sys.executable, "-m", "d5rl.cli", *args], env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def published(task_id: str, agents: tuple[str, ...]):
    """The task's spec as it is once ``agents`` are published with the stand-in training logs."""
    spec = d5rl.get_spec(task_id)
    n = len(agents) * sum(s["episodes"] for s in SEGMENTS)
    return dataclasses.replace(spec, dataset=dataclasses.replace(spec.dataset, num_episodes=n, unavailable=None))


@pytest.fixture(scope="module")
def hiking_home(policies, tmp_path_factory) -> Path:
    """D5RL_HOME holding the whole stand-in a1-v1-hiking dataset (4 episodes of goals-mixed-v1), verified."""
    home = tmp_path_factory.mktemp("home")
    d5rl_cli(policies, home, "generate", "a1-hiking-v1")
    assert d5rl_cli(policies, home, "verify", "a1-hiking-v1").startswith("OK: 1 shards intact")
    return home


@pytest.fixture
def hiking_data(hiking_home, policies, monkeypatch):
    monkeypatch.setenv("D5RL_HOME", str(hiking_home))
    monkeypatch.setattr(a1_data, "POLICY_DIR", policies)  # what D5RL_A1_POLICIES does in a new process
    return load_dataset(published("a1-hiking-v1", ("goals-mixed-v1",)), generate=False, progress=False, in_memory=True)


def test_generation_runs_the_policies_without_xla():
    """Portable bytes need CPU-independent policy inference: the generator's numpy MLP, never JAX."""
    code = "import sys, d5rl.production.a1.data, d5rl.datasets.generation; print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'flax')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True).stdout
    assert out.strip() == "[]"


def test_v1_datasets_are_portable_and_replay_their_scenes():
    for task, agents in (
        ("a1-walk-v1", SPEED_AGENTS_V1),
        ("a1-run-v1", SPEED_AGENTS_V1),
        ("a1-hiking-v1", HIKING_AGENTS_V1),
    ):
        dspec = d5rl.get_spec(task).dataset
        assert dspec.numerics == "portable" and dspec.replay == "d5rl.production.a1.data:replay_env"
        if buffer_episodes(agents):  # published: the size is what the agents' training logs say they collected
            assert dspec.unavailable is None and dspec.num_episodes == buffer_episodes(agents) > 100
        else:
            assert "not published yet" in dspec.unavailable


def test_generated_v1_hiking_data_replays_on_its_own_floors(hiking_data):
    ds = hiking_data
    assert ds.metadata["numerics"] == "portable" and ds.num_episodes == 4
    assert [m["agent"] for m in ds.episode_meta] == ["goals-mixed-v1"] * 4
    assert sorted(m["segment"] for m in ds.episode_meta) == [0, 0, 1, 2]
    assert ds.arrays["observations"].shape[1] == 60
    bumpy_seen = set()
    for i in range(ds.num_episodes):
        ep = ds.episode(i)
        seed = ep.meta["reset_seed"]
        # the scene drawn independently from the stored seed, in RunToward's order: floor kind (and heights),
        # friction, trunk mass, first goal (gymnasium seeds the env's generator as default_rng(seed))
        rng = np.random.default_rng(seed)
        bumpy = bool(rng.integers(2))
        heights = arenas.field_data("bumpy", rng) if bumpy else None
        friction = rng.uniform(*v1.FRICTION_RANGE)
        mass = rng.uniform(v1.TRUNK_MASS - v1.TRUNK_MASS_SPREAD, v1.TRUNK_MASS + v1.TRUNK_MASS_SPREAD)
        goal = rng.uniform(-v1.GOAL_RANGE, v1.GOAL_RANGE, 2)
        bumpy_seen.add(bumpy)

        env = replay_env(d5rl.get_spec("a1-hiking-v1"), ep.meta)
        m = env.model
        assert m.geom(arenas.FIELD).pos[2] == (arenas.FIELD_Z if bumpy else -10.0)
        if bumpy:
            np.testing.assert_array_equal(m.hfield_data, heights.astype(np.float32))
        assert m.geom("floor").friction[0] == m.geom(arenas.FIELD).friction[0] == friction
        assert m.body("trunk").mass[0] == mass
        np.testing.assert_array_equal(env.task.goal, goal)

        states, actions, obs = ep.arrays["states"], ep.arrays["actions"], ep.arrays["observations"]
        env.set_state(states[0])
        np.testing.assert_allclose(env._obs(), obs[0], atol=1e-5)
        replayed = [env.replay_step(s, a) for s, a in zip(states[1:], actions)]
        np.testing.assert_allclose(replayed, obs[1:], atol=1e-5)  # heading terms: the goals as drawn then
        # the scene is the one the episode ran on: the stored action takes a stored state to the next one
        t = len(actions) // 2
        env.set_state(states[t])
        env.step(actions[t])
        np.testing.assert_allclose(env.get_state(), states[t + 1], rtol=1e-7, atol=1e-9)
        env.close()
    assert bumpy_seen == {False, True}


def test_the_tasks_own_env_would_not_replay_a_bumpy_episode(hiking_data):
    """Why the replay env exists: on the hiking course (or any other floor) the stored dynamics break."""
    ep = next(
        e
        for e in hiking_data.episodes()
        if replay_env(d5rl.get_spec("a1-hiking-v1"), e.meta).model.geom(arenas.FIELD).pos[2] == arenas.FIELD_Z
    )
    env = make_env("a1-hiking-v1").unwrapped
    env.reset(seed=0)
    states, actions = ep.arrays["states"], ep.arrays["actions"]
    env.set_state(states[0])
    env.step(actions[0])
    assert not np.allclose(env.get_state(), states[1], rtol=1e-7, atol=1e-9)


def test_render_episode_replays_on_the_episodes_floor(hiking_data, hiking_home, policies, tmp_path):
    from d5rl.registry import make_replay_env

    i = next(
        i
        for i, m in enumerate(hiking_data.episode_meta)
        if replay_env(d5rl.get_spec("a1-hiking-v1"), m).model.geom(arenas.FIELD).pos[2] == arenas.FIELD_Z
    )
    env = make_replay_env("a1-hiking-v1", hiking_data.episode_meta[i])  # the dataset's replay, not the course
    assert isinstance(env.task, v1.RunToward) and not isinstance(env.task, v1.Hiking)
    env.close()
    out = tmp_path / "episode.mp4"
    d5rl_cli(policies, hiking_home, "render", "a1-hiking-v1", "--episode", str(i), "--steps", "2", "--out", str(out))
    assert out.stat().st_size > 0


def test_v1_datacard_stage_shares_and_speed_histogram(hiking_data):
    from d5rl.production.a1.datacard_stats import describe, stage_shares

    lengths = [len(hiking_data.episode(i).arrays["actions"]) for i in range(hiking_data.num_episodes)]
    by_stage = {}
    for m, n in zip(hiking_data.episode_meta, lengths):
        by_stage[m["segment"]] = by_stage.get(m["segment"], 0) + n
    expected = [
        (seg, SEGMENTS[seg]["snapshot"] or "random", SEGMENTS[seg]["start_step"], by_stage[seg] / sum(lengths))
        for seg in sorted(by_stage)
    ]
    got = stage_shares(hiking_data)["goals-mixed-v1"]
    assert [g[:3] for g in got] == [e[:3] for e in expected]
    np.testing.assert_allclose([g[3] for g in got], [e[3] for e in expected])

    speeds = np.concatenate([hiking_data.episode(i).arrays["infos/forward_speed"] for i in range(4)])
    counts, _ = np.histogram(np.clip(speeds, -0.2, 1.2 - 1e-9), np.arange(-0.2, 1.2 + 1e-9, 0.1))
    text = describe((published("a1-hiking-v1", ("goals-mixed-v1",)),))
    assert "`a1-v1-hiking` (used by `a1-hiking-v1`)" in text
    assert f"| 0: random | {100 * expected[0][3]:.1f}% (step 0) |" in text
    table = text[text.index("| forward speed (m/s) | all steps | `goals-mixed-v1` |") :].splitlines()[2:]
    assert [r.split(" | ")[-1].rstrip(" |") for r in table] == [f"{100 * c / counts.sum():.1f}%" for c in counts]


def test_v1_locomotion_generate_verify_load(policies, tmp_path, monkeypatch):
    d5rl_cli(policies, tmp_path, "generate", "a1-walk-v1", "--episodes", "6")
    assert d5rl_cli(policies, tmp_path, "verify", "a1-walk-v1").startswith("OK: 1 shards intact")
    monkeypatch.setenv("D5RL_HOME", str(tmp_path))
    monkeypatch.setattr(a1_data, "POLICY_DIR", policies)
    walk = load_dataset(
        published("a1-walk-v1", tuple(a for a in V1_AGENTS if a.startswith("speed"))), generate=False, progress=False
    )
    assert walk.num_episodes == 6 and walk.arrays["observations"].shape[1] == 58
    assert {m["agent"] for m in walk.episode_meta} <= {"speed-0.5-v1", "speed-0.8-v1", "speed-1.0-v1"}
    ep = walk.episode(0)
    env = replay_env(d5rl.get_spec("a1-walk-v1"), ep.meta)
    replayed = [env.replay_step(s, a) for s, a in zip(ep.arrays["states"][1:], ep.arrays["actions"])]
    np.testing.assert_allclose(replayed, ep.arrays["observations"][1:], atol=1e-5)


def test_calibrate_v1_with_stand_in_agents(policies, tmp_path):
    result = json.loads(d5rl_cli(policies, tmp_path, "calibrate", "a1-walk-v1", "--episodes", "1", "--dry-run"))
    env = make_env("a1-walk-v1")
    rng, returns, lengths = np.random.default_rng(0), [], []
    for i in range(1):  # uniform random actions in v1's box, as calibrate's random reference defines them
        env.reset(seed=i)
        total, done, n = 0.0, False, 0
        while not done:
            _, r, term, trunc, _ = env.step(rng.uniform(-1.0, 1.0, 12).astype(np.float32))
            total, done, n = total + r, term or trunc, n + 1
        returns.append(total)
        lengths.append(n)
    assert result["random"] == pytest.approx(np.mean(returns), abs=1e-3)
    assert max(lengths) < 400  # random actions in the release's range fall (v0's never did)
    candidates = ("speed-0.5-v1", "speed-0.8-v1", "speed-1.0-v1", "run-1.25-v1")
    assert set(result["per_agent"]) == set(candidates)
    from d5rl.production.a1.policy import run_episodes

    for agent in candidates:
        r = run_episodes(env, SnapshotPolicy(policies / agent / "final.npz"), 1, 0)
        assert result["per_agent"][agent] == pytest.approx(np.mean(r["returns"]), abs=1e-3), agent
    assert result["expert_agent"] == max(result["per_agent"], key=result["per_agent"].get)
    assert result["expert"] == result["per_agent"][result["expert_agent"]]
    assert result["expert_trained"].startswith("SAC, 1,600 steps, tracking ")


def test_smooth_hiking_variant_holds_goals_smooth_episodes_on_the_plane(policies, tmp_path, monkeypatch):
    """a1-hiking-smooth-v1: the other hiking data candidate, for BC on the course against a1-hiking-v1."""
    spec = d5rl.get_spec("a1-hiking-smooth-v1")
    assert spec.variant_of == "a1-hiking-v1" and spec.dataset.generator_kwargs == {"agents": ("goals-smooth-v1",)}
    d5rl_cli(policies, tmp_path, "generate", "a1-hiking-smooth-v1", "--episodes", "4")
    monkeypatch.setenv("D5RL_HOME", str(tmp_path))
    monkeypatch.setattr(a1_data, "POLICY_DIR", policies)
    n = sum(s["episodes"] for s in SEGMENTS)
    ds = load_dataset(
        dataclasses.replace(spec, dataset=dataclasses.replace(spec.dataset, num_episodes=n, unavailable=None)),
        generate=False,
        progress=False,
        episodes=4,
    )
    for m in ds.episode_meta:
        assert m["agent"] == "goals-smooth-v1"
        env = replay_env(spec, m)
        assert env.model.geom(arenas.FIELD).pos[2] == -10.0 and not env.task.bumpy  # no episode on the bumps
        env.close()


def test_browse_renders_an_episode_on_its_own_floor(hiking_data):
    frames = pytest.importorskip("d5rl.browse.frames")
    from d5rl.video import replay_frames

    ep = hiking_data.episode(0)
    spec = d5rl.get_spec("a1-hiking-v1")
    shown = frames.render_states(spec, ep.arrays["states"][:2], ep.meta)["observations/pixels/view"]
    expected = np.stack(
        list(
            replay_frames(
                replay_env(spec, ep.meta, render_mode="rgb_array"),
                ep.arrays["states"][:2],
                frames.ENV_VIEW_SIZE,
                "fast",
            )
        )
    )
    np.testing.assert_array_equal(shown, expected)
    course = make_env("a1-hiking-v1", render_mode="rgb_array")
    course.reset(seed=0)
    on_course = np.stack(list(replay_frames(course, ep.arrays["states"][:2], frames.ENV_VIEW_SIZE, "fast")))
    assert not np.array_equal(shown, on_course)  # the task's env would show the course around the robot


@pytest.mark.slow
def test_trained_and_published_agent_generates_v1_data(policies, tmp_path, monkeypatch):
    """The real path: a tiny run of the v1 trainer, `publish` into the policy directory, then `d5rl generate`."""
    pytest.importorskip("jax")
    shipped = tmp_path / "policies"
    for agent in ("speed-0.8-v1", "speed-1.0-v1"):  # stand-ins for the other two data agents
        for f in (policies / agent).iterdir():
            (shipped / agent).mkdir(parents=True, exist_ok=True)
            (shipped / agent / f.name).write_bytes(f.read_bytes())
    trainer = ["-m", "d5rl.production.a1.experts"]
    env = {
        **os.environ,
        "D5RL_A1_POLICIES": str(shipped),
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    for args in (
        [
            "train",
            "--agents",
            "speed-0.5-v1",
            "--steps",
            "500",
            "--start-steps",
            "200",
            "--first-segment",
            "100",
            "--snapshot-every",
            "200",
            "--utd",
            "1",
            "--work-dir",
            str(tmp_path / "work"),
            "--policy-dir",
            str(tmp_path / "trained"),
            "--saved-dir",
            str(tmp_path / "saved"),
        ],
        ["publish", "--agents", "speed-0.5-v1", "--policy-dir", str(tmp_path / "trained")],
    ):
        proc = subprocess.run([sys.executable, *trainer, *args], env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
    log = json.loads((shipped / "speed-0.5-v1" / "log.json").read_text())
    assert [s["snapshot"] for s in log["segments"]] == [None, "snapshot-01.npz", "snapshot-02.npz"]
    n = sum(s["episodes"] for s in log["segments"]) + 2 * sum(s["episodes"] for s in SEGMENTS)
    d5rl_cli(shipped, tmp_path / "home", "generate", "a1-walk-v1")
    assert d5rl_cli(shipped, tmp_path / "home", "verify", "a1-walk-v1").startswith("OK: ")
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "home"))
    monkeypatch.setattr(a1_data, "POLICY_DIR", shipped)
    spec = d5rl.get_spec("a1-walk-v1")
    ds = load_dataset(
        dataclasses.replace(spec, dataset=dataclasses.replace(spec.dataset, num_episodes=n, unavailable=None)),
        generate=False,
        progress=False,
    )
    trained = [m for m in ds.episode_meta if m["agent"] == "speed-0.5-v1"]
    by_segment = {i: sum(m["segment"] == i for m in trained) for i in range(3)}
    assert by_segment == {i: s["episodes"] for i, s in enumerate(log["segments"])}  # the buffer, episode for episode
    assert {m["snapshot"] for m in trained} == {"random", "snapshot-01.npz", "snapshot-02.npz"}


def test_calibrate_v1_hiking_picks_among_the_goal_agents_and_the_course_reference(policies, tmp_path):
    result = json.loads(d5rl_cli(policies, tmp_path, "calibrate", "a1-hiking-v1", "--episodes", "1", "--dry-run"))
    assert set(result["per_agent"]) == {"goals-mixed-v1", "goals-smooth-v1", "hiking-v1"}
    env = make_env("a1-hiking-v1")
    from d5rl.production.a1.policy import run_episodes

    for agent, ret in result["per_agent"].items():  # 60-D observations: the heading error to the next waypoint
        r = run_episodes(env, SnapshotPolicy(policies / agent / "final.npz"), 1, 0)
        assert ret == pytest.approx(np.mean(r["returns"]), abs=1e-3), agent
    assert result["expert"] == max(result["per_agent"].values())
    assert "toward random goals" in result["expert_trained"] or "hiking course" in result["expert_trained"]


def test_data_from_other_policy_files_is_not_the_published_agents_data(policies, hiking_home, tmp_path):
    """The identity names the policy files by digest: with one snapshot changed (a trial agent, or a
    newer publication), the dataset on disk is reported as made by other inputs instead of being used."""
    import shutil

    other = tmp_path / "policies"
    shutil.copytree(policies, other)
    save_actor(
        _actor(np.random.default_rng(1), AGENTS["goals-mixed-v1"].obs_dim), other / "goals-mixed-v1" / "snapshot-01.npz"
    )
    env = {
        **os.environ,
        "D5RL_A1_POLICIES": str(other),
        "D5RL_HOME": str(hiking_home),
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    proc = subprocess.run(
        [sys.executable, "-m", "d5rl.cli", "verify", "a1-hiking-v1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode != 0
    assert "generator_inputs" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    d5rl_cli(policies, hiking_home, "verify", "a1-hiking-v1")  # the files it was made from: intact

    from d5rl.datasets import generation
    from d5rl.production.a1.data import policy_digest

    spec = published("a1-hiking-v1", ("goals-mixed-v1",))
    recorded = {
        **generation.data_identity(spec),
        "generator_inputs": {"goals-mixed-v1": policy_digest("goals-mixed-v1", other)},
    }
    assert "other generator inputs" in generation.stale_data(spec, recorded)
    assert generation.stale_data(spec, generation.data_identity(spec)) is None
    assert generation.data_identity(spec)["generator_inputs"] == {"goals-mixed-v1": policy_digest("goals-mixed-v1")}
