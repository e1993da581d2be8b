"""The A1 agents' trainer: training reward, snapshots and logs, exact resume."""

import json

import numpy as np
import pytest

from d5rl.envs.a1 import rewards
from d5rl.production.a1.agents import AGENTS, AgentSpec, make_env, training_reward

pytest.importorskip("jax")


def test_training_reward_with_the_task_band_is_the_task_reward():
    for agent in ("speed-0.8", "heading"):
        env = make_env(agent)
        env.reset(seed=3)
        spec = AGENTS[agent]
        task_band = AgentSpec(spec.target_speed, spec.command, spec.terrain, band=(-0.1, 0.1))
        rng = np.random.default_rng(0)
        for _ in range(30):
            _, r, term, _, info = env.step(rng.uniform(-1, 1, 12))
            assert training_reward(task_band, info) == pytest.approx(r, abs=1e-9)
            if term:
                break


def test_narrow_band_rewards_the_target_not_the_slow_edge():
    spec = AGENTS["speed-1.0"]
    info = {"standing": 1.0, "energy": 0.0}
    at_target = training_reward(spec, {**info, "forward_speed": 1.0})
    slow_edge = training_reward(spec, {**info, "forward_speed": 0.9})
    assert at_target == pytest.approx(rewards.SPEED_REWARD_SCALE)
    # the task's reward is flat down to 0.9 m/s; the training reward falls by 0.1 / margin (1.0) there
    assert slow_edge == pytest.approx(rewards.SPEED_REWARD_SCALE * 0.9)
    assert rewards.speed_term(0.9, 1.0) == 1.0


def test_trainer_writes_snapshots_logs_and_resumes_bit_for_bit(tmp_path, small_trainer):
    def train(name, max_minutes=None):
        t = small_trainer(["speed-0.5", "run-1.25"], tmp_path / name / "work", policy_dir=tmp_path / name / "policies")
        return t.run(max_minutes=max_minutes, log_every=10**9)

    assert train("straight")
    # the same run stopped at every snapshot boundary and resumed
    stops = 0
    while not train("resumed", max_minutes=0):
        stops += 1
    assert stops == 2  # boundaries at steps 30 and 60 (start_steps 30, snapshot_every 30)
    for agent in ("speed-0.5", "run-1.25"):
        a, b = tmp_path / "straight" / "policies" / agent, tmp_path / "resumed" / "policies" / agent
        assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())
        for f in a.glob("*.npz"):
            with np.load(f) as x, np.load(b / f.name) as y:
                assert x.files == y.files and all(np.array_equal(x[k], y[k]) for k in x.files), f.name
        la, lb = json.loads((a / "log.json").read_text()), json.loads((b / "log.json").read_text())
        assert la["segments"] == lb["segments"]
    data = tmp_path / "straight" / "policies" / "speed-0.5"
    log = json.loads((data / "log.json").read_text())
    assert [s["snapshot"] for s in log["segments"]] == [None, "snapshot-01.npz", "snapshot-02.npz"]
    assert [s["start_step"] for s in log["segments"]] == [0, 30, 60]
    assert sum(s["steps"] for s in log["segments"]) == 90
    # a reference agent saves snapshots too (a resume on another machine replays them)
    assert sorted(p.name for p in (tmp_path / "straight" / "policies" / "run-1.25").glob("*.npz")) == [
        "final.npz",
        "snapshot-01.npz",
        "snapshot-02.npz",
    ]


def test_snapshot_boundaries_double_from_the_first_segment():
    from d5rl.production.a1.experts import boundaries

    assert sorted(boundaries(5000, 1250, 20000, 80000)) == [5000, 6250, 8750, 13750, 23750, 43750, 63750]
    # uniform segments when the first is as long as the rest (the default)
    assert sorted(boundaries(30, 30, 30, 90)) == [30, 60, 90]


def test_trainer_snapshots_on_the_doubling_schedule(tmp_path, small_trainer):
    small_trainer(["speed-0.5"], tmp_path / "work", steps=75, snapshot_every=20, first_segment=5).run(log_every=10**9)
    log = json.loads((tmp_path / "policies" / "speed-0.5" / "log.json").read_text())
    assert [s["start_step"] for s in log["segments"]] == [0, 30, 35, 45, 65]
    assert [s["steps"] for s in log["segments"]] == [30, 5, 10, 20, 10]
    assert log["first_segment"] == 5


def test_trainer_refuses_mixed_observation_sizes(tmp_path, small_trainer):
    with pytest.raises(ValueError, match="observation sizes"):
        small_trainer(["speed-0.5", "heading"], tmp_path, steps=10, snapshot_every=5, start_steps=5)


@pytest.mark.slow
def test_v1_agents_train_resume_from_an_export_and_check(tmp_path, capsys, small_trainer):
    """The v1 agents (the release's tasks) go through the same trainer: snapshots, export without buffers,
    resume elsewhere with the buffer refilled on the v1 envs, a reference trained from a data agent, check."""
    from d5rl.production.a1.experts import main
    from d5rl.production.a1.resume import export

    policies, saved = tmp_path / "policies", tmp_path / "saved"

    def trainer(machine, agents=("goals-mixed-v1", "goals-smooth-v1")):
        work = tmp_path / machine / "+".join(agents)
        return small_trainer(agents, work, steps=40, snapshot_every=20, start_steps=20, saved_root=saved)

    assert not trainer("a").run(max_minutes=0, log_every=10**9)  # stops at the first boundary (step 20)
    export(tmp_path / "a", saved)
    assert trainer("b").run(log_every=10**9)  # resumes from the export, refilling 20 steps per agent
    log = json.loads((policies / "goals-mixed-v1" / "log.json").read_text())
    assert [s["start_step"] for s in log["segments"]] == [0, 20] and log["steps"] == 40
    assert log["env_version"] == 1 and log["task"] == "run_toward" and log["floors"] == "mixed"
    for f in ("snapshot-01.npz", "final.npz"):
        assert (policies / "goals-smooth-v1" / f).exists()
    # the hiking reference starts from the goals agent's final learner
    learners = tmp_path / "b" / "learners"
    assert (learners / "goals-mixed-v1.msgpack").exists()
    hiking = small_trainer(
        ["hiking-v1"],
        tmp_path / "b" / "hiking-v1",
        steps=25,
        snapshot_every=20,
        start_steps=20,
        init_from="goals-mixed-v1",
    )
    assert hiking.run(log_every=10**9)
    main(["check", "--agents", "goals-smooth-v1", "--episodes", "1", "--policy-dir", str(policies)])
    out = capsys.readouterr().out
    assert "| `goals-smooth-v1` | deterministic | 1.00 |" in out
