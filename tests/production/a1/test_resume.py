"""A1 training across machines: a checkpoint exported without its replay buffer resumes elsewhere."""

import json

import numpy as np
import pytest

pytest.importorskip("jax")


def test_exported_checkpoint_resumes_on_a_machine_without_the_buffer(tmp_path, small_trainer):
    from d5rl.production.a1.resume import export
    from d5rl.training.checkpoint import load_checkpoint

    def trainer(work):
        return small_trainer(["speed-0.5", "run-1.25"], work / "speed-0.5+run-1.25", saved_root=tmp_path / "saved")

    assert not trainer(tmp_path / "machine-a").run(max_minutes=0, log_every=10**9)  # stops at step 30
    export(tmp_path / "machine-a", tmp_path / "saved")
    full = load_checkpoint(tmp_path / "machine-a" / "speed-0.5+run-1.25")
    saved = load_checkpoint(tmp_path / "saved" / "checkpoints" / "speed-0.5+run-1.25")
    assert saved.buffer is None and saved.agent == full.agent and saved.state == full.state
    assert not (tmp_path / "saved" / "checkpoints" / "speed-0.5+run-1.25" / "checkpoint.prev").exists()

    # training time adds up over resumed processes: pretend the first one took 1000 s
    from d5rl.training.checkpoint import Checkpoint, save_checkpoint

    save_checkpoint(
        tmp_path / "saved" / "checkpoints" / "speed-0.5+run-1.25",
        Checkpoint(saved.agent, {**saved.state, "train_seconds": 1000}),
    )
    b = trainer(tmp_path / "machine-b")  # no checkpoint of its own
    learners = b._new_learners()
    _, t, _, _, segments = b._load(learners)
    assert t == 30 and [s.snapshot for s in segments[0]] == [None, "snapshot-01.npz"]
    # the refilled buffer: 30 random-action steps per agent, chained observations, the training reward
    for i in range(2):
        acts = b.buf["actions"][i, :30]
        assert np.all(np.abs(acts) <= 1) and np.abs(acts).sum() > 0 and not b.buf["actions"][i, 30:].any()
        cont = b.buf["masks"][i, :29] > 0
        same = np.all(b.buf["next_observations"][i, :29] == b.buf["observations"][i, 1:30], axis=1)
        assert same[cont].all()  # equal except where an episode ended (a fall)
    assert b.run(log_every=10**9)  # and training finishes from there
    log = json.loads((tmp_path / "policies" / "speed-0.5" / "log.json").read_text())
    assert [s["start_step"] for s in log["segments"]] == [0, 30, 60]
    assert 1000 <= log["train_seconds"] < 1000 + 600


def test_training_time_of_a_checkpoint_from_before_it_was_stored_comes_from_the_logs(tmp_path, small_trainer):
    from d5rl.training.checkpoint import Checkpoint, load_checkpoint, save_checkpoint

    def trainer():
        return small_trainer(["speed-0.5"], tmp_path / "work", steps=60)

    assert not trainer().run(max_minutes=0, log_every=10**9)
    ckpt = load_checkpoint(tmp_path / "work")
    old_state = {k: v for k, v in ckpt.state.items() if k != "train_seconds"}
    save_checkpoint(tmp_path / "work", Checkpoint(ckpt.agent, old_state, ckpt.buffer))
    log_file = tmp_path / "policies" / "speed-0.5" / "log.json"
    log_file.write_text(json.dumps({**json.loads(log_file.read_text()), "train_seconds": 500}))
    assert trainer().run(log_every=10**9)
    assert json.loads(log_file.read_text())["train_seconds"] >= 500


def test_publish_ships_a_data_agents_snapshots_and_a_reference_agents_final_policy(tmp_path, small_trainer):
    from d5rl.errors import D5RLError
    from d5rl.production.a1.resume import publish

    trained, shipped = tmp_path / "policies", tmp_path / "shipped"
    t = small_trainer(["speed-0.5", "run-1.25"], tmp_path / "work", steps=60)
    assert not t.run(max_minutes=0, log_every=10**9)  # stopped at step 30: not finished
    with pytest.raises(D5RLError, match="has not finished"):
        publish(["speed-0.5"], trained, shipped)
    assert not shipped.exists()
    assert t.run(log_every=10**9)
    (shipped / "speed-0.5").mkdir(parents=True)
    (shipped / "speed-0.5" / "snapshot-07.npz").write_bytes(b"old")  # an older agent's snapshot goes
    publish(["speed-0.5", "run-1.25"], trained, shipped)
    assert sorted(p.name for p in (shipped / "speed-0.5").iterdir()) == ["final.npz", "log.json", "snapshot-01.npz"]
    assert sorted(p.name for p in (shipped / "run-1.25").iterdir()) == ["final.npz", "log.json"]
    assert (shipped / "speed-0.5" / "final.npz").read_bytes() == (trained / "speed-0.5" / "final.npz").read_bytes()
