import dataclasses

import numpy as np
import pytest

import d5rl
from d5rl.datasets.generation import episode_rng, make_generator
from d5rl.envs.a1.published import POLICY_DIR
from d5rl.production.a1 import data
from d5rl.production.a1.agents import AGENTS
from d5rl.production.a1.calibrate import evaluate
from d5rl.production.a1.policy import SnapshotPolicy


def test_data_agents_policies_ship_with_the_package():
    # (reference agents ship their final policy only; `registration.SCORE_AGENTS` lists the candidates)
    # (v1 data agents ship once trained: registration says so until then)
    for agent in (
        a for a, spec in AGENTS.items() if spec.role == "data" and (spec.env_version == 0 or (POLICY_DIR / a).exists())
    ):
        log = POLICY_DIR / agent / "log.json"
        assert log.exists() and (POLICY_DIR / agent / "final.npz").exists(), agent
        for seg in data.agent_log(agent)["segments"]:
            assert seg["snapshot"] is None or (POLICY_DIR / agent / seg["snapshot"]).exists(), (agent, seg)


def _first_index_of(gen, agent, learned=True):
    for i, (a, seg) in enumerate(gen.table):
        if a == agent and (seg > 0) == learned:
            return i
    raise AssertionError(f"no episode of {agent}")


def test_generator_is_deterministic_and_covers_every_stage():
    spec = d5rl.get_spec("a1-walk-v0")
    gen = make_generator(spec)
    assert len(gen.table) == spec.dataset.num_episodes
    assert {a for a, _ in gen.table} == {"speed-0.5", "speed-0.8", "speed-1.0"}
    segs = {(a, s) for a, s in gen.table}
    for agent in ("speed-0.5", "speed-0.8", "speed-1.0"):
        assert (agent, 0) in segs  # random exploration before learning
        assert max(s for a, s in segs if a == agent) >= 3  # several learned snapshots
    i = _first_index_of(gen, "speed-0.8")
    a, b = gen.episode(i, episode_rng(0, i)), make_generator(spec).episode(i, episode_rng(0, i))
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    c = gen.episode(i, episode_rng(1, i))
    assert not np.array_equal(a.arrays["actions"], c.arrays["actions"])


def test_relabel_reproduces_the_agents_own_reward():
    spec = d5rl.get_spec("a1-walk-v0")
    gen = make_generator(spec)
    i = _first_index_of(gen, "speed-0.5")
    ep = gen.episode(i, episode_rng(0, i))
    own = dataclasses.replace(spec, env_kwargs={"target_speed": 0.5})
    np.testing.assert_allclose(data.relabel_speed(own, ep.arrays)["rewards"], ep.arrays["rewards"], atol=1e-3)
    walk = data.relabel_speed(spec, ep.arrays)["rewards"]
    assert not np.allclose(walk, ep.arrays["rewards"], atol=1e-2)


def test_hiking_relabel_matches_heading_agent_reward():
    spec = d5rl.get_spec("a1-hiking-v0")
    gen = make_generator(spec)
    ep = gen.episode(0, episode_rng(0, 0))
    np.testing.assert_allclose(data.relabel_hiking(spec, ep.arrays)["rewards"], ep.arrays["rewards"], atol=1e-3)
    assert ep.arrays["observations"].shape[1] == 60


@pytest.mark.slow
@pytest.mark.parametrize(
    "agent, low, high",
    [
        ("speed-0.5", 0.475, 0.525),
        ("speed-0.8", 0.76, 0.84),  # the speed bar: within 5% of the target
        ("speed-1.0", 0.85, 1.05),  # at this actuation's ceiling (~0.9 m/s, A1 data card), not at 1.0
        ("hiking", 0.65, 0.85),  # the course reference, on the course
    ],
)
def test_shipped_agents_track_their_speed_without_falling(agent, low, high):
    from d5rl.production.a1.speedcheck import rollouts

    r = rollouts(agent, episodes=2, seed=0, deterministic=True)  # whole episodes from rest, as `check`
    assert not any(r["falls"])
    assert low <= np.mean(r["speeds"]) <= high, r["speeds"]


@pytest.mark.slow
def test_expert_beats_random_on_walk():
    rnd = np.mean(evaluate("a1-walk-v0", SnapshotPolicy(None), 3, 0, deterministic=False)["returns"])
    best = max(
        np.mean(evaluate("a1-walk-v0", SnapshotPolicy(POLICY_DIR / a / "final.npz"), 3, 0)["returns"])
        for a in ("speed-0.5", "speed-0.8", "speed-1.0")
    )
    assert best > 2 * rnd


def test_calibration_records_the_experts_speed(monkeypatch, capsys):
    """calibrate stores each agent's mean forward speed next to its return; `d5rl info` says how fast the expert is."""
    from d5rl.cli import main
    from d5rl.envs.a1.registration import _ref
    from d5rl.production.a1 import calibrate as cal

    r = evaluate("a1-walk-v0", SnapshotPolicy(POLICY_DIR / "speed-0.8" / "final.npz"), 1, 0)
    assert len(r["returns"]) == len(r["speeds"]) == 1 and 0.3 < r["speeds"][0] < 1.2  # the 0.8 m/s agent walks
    monkeypatch.setattr(cal, "SCORE_AGENTS", {"a1-walk-v0": ("speed-0.5", "speed-0.8")})

    class Named:  # stands for a snapshot: which agent it is
        def __init__(self, path):
            self.name = path.parent.name if path else "random"

    returns, agent_speeds = (
        {"random": 100.0, "speed-0.5": 200.0, "speed-0.8": 300.0},
        {"speed-0.5": 0.5, "speed-0.8": 0.7},
    )

    def fake_evaluate(task, policy, episodes, seed, deterministic=True):
        return {"returns": [returns[policy.name]] * episodes, "speeds": [agent_speeds.get(policy.name, 0.0)] * episodes}

    monkeypatch.setattr(cal, "SnapshotPolicy", Named)
    monkeypatch.setattr(cal, "evaluate", fake_evaluate)
    result = cal.calibrate("a1-walk-v0", episodes=2)
    assert result["expert_agent"] == "speed-0.8" and result["expert_speed"] == 0.7
    assert result["per_agent_speed"] == {"speed-0.5": 0.5, "speed-0.8": 0.7}
    ref = _ref("a1-walk-v0", {"a1-walk-v0": result})
    steps = data.agent_log("speed-0.8")["steps"]
    assert result["expert_trained"] == f"SAC, {steps:,} steps, tracking 0.8 m/s on flat ground"
    assert ref.expert == 300.0 and ref.expert_note == (
        f"'speed-0.8' (SAC, {steps:,} steps, tracking 0.8 m/s on flat ground) runs 0.70 m/s on average on this task"
    )
    assert main(["info", "a1-walk-v0"]) == 0
    assert "the expert: 'speed-0.8' (SAC, " in capsys.readouterr().out  # the committed scores.json has both


def test_speed_histogram_shares_per_column():
    from d5rl.production.a1.datacard_stats import speed_histogram

    table = speed_histogram({"a": np.array([0.05, 0.05, 0.55, 2.0]), "b": np.array([-1.0])}).splitlines()
    assert table[0] == "| forward speed (m/s) | a | b |"
    rows = {r.split(" | ")[0].lstrip("| "): r.split(" | ")[1:] for r in table[2:]}
    assert rows["-0.2 … -0.1"] == ["0.0%", "100.0% |"]  # below the range: the first bin
    assert rows["+0.0 … +0.1"][0] == "50.0%" and rows["+0.5 … +0.6"][0] == "25.0%"
    assert rows["≥ +1.1"][0] == "25.0%"  # the last bin is open
