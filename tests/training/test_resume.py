"""Exact resume after a kill (offline and online), and online fine-tuning."""

import json

import numpy as np
import pytest

from d5rl.production.toy.data import toy_dataset
from d5rl.settings import resolve
from d5rl.training.loop import train
from tests.training.helpers import interrupt_after_checkpoint, leaves, overrides, rows


def assert_offline_resume_is_exact(tmp_path, algo, task, steps, kw, ds, interrupt_at):
    """A run killed after its checkpoint at ``interrupt_at`` and resumed ends where an unbroken run does."""
    full = train(resolve(algo, task, kw, offline_steps=steps, seed=1), tmp_path / "a", dataset=ds)
    with pytest.raises(KeyboardInterrupt), interrupt_after_checkpoint(interrupt_at):
        train(resolve(algo, task, kw, offline_steps=steps, seed=1), tmp_path / "b", dataset=ds)
    first_process = json.loads((tmp_path / "b" / "checkpoint" / "state.json").read_text())["elapsed_s"]
    resumed = train(resolve(algo, task, kw, offline_steps=steps, seed=1), tmp_path / "b", dataset=ds)
    for a, b in zip(leaves(full["agent"]), leaves(resumed["agent"])):
        np.testing.assert_array_equal(a, b)
    assert rows(tmp_path / "a") == rows(tmp_path / "b")
    assert (full["resumed"], resumed["resumed"]) == (False, True)
    assert first_process > 0 and resumed["run_wall_s"] >= first_process  # both processes count


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
    full = train(
        resolve("rlpd", "toy-reach-v0", kw, offline_steps=0, online_steps=75, seed=2), tmp_path / "a", dataset=ds
    )
    with pytest.raises(KeyboardInterrupt), interrupt_after_checkpoint(20):
        train(resolve("rlpd", "toy-reach-v0", kw, offline_steps=0, online_steps=75, seed=2), tmp_path / "b", dataset=ds)
    state_step = json.loads((tmp_path / "b" / "checkpoint" / "state.json").read_text())["step"]
    assert state_step == 25  # the checkpoint due at step 20 waits for the episode end
    resumed = train(
        resolve("rlpd", "toy-reach-v0", kw, offline_steps=0, online_steps=75, seed=2), tmp_path / "b", dataset=ds
    )
    for a, b in zip(leaves(full["agent"]), leaves(resumed["agent"])):
        np.testing.assert_array_equal(a, b)
    assert rows(tmp_path / "a") == rows(tmp_path / "b")
    returns = [r["train/episode_return"] for r in rows(tmp_path / "a") if "train/episode_return" in r]
    assert len(returns) == 3


def test_calql_online_finetuning_runs(tmp_path):
    ds = toy_dataset(10)
    res = train(
        resolve(
            "calql", "toy-reach-v0", overrides(cql_n_actions=2, eval_interval=1000), offline_steps=16, online_steps=30
        ),
        tmp_path / "c",
        dataset=ds,
    )
    assert res["step"] == 46 and np.isfinite(res["return"])


class _Counting:
    """An agent's ``eval_actions``, counted; raises KeyboardInterrupt (a kill) at call ``kill_at``."""

    def __init__(self, agent, kill_at=None):
        self.agent, self.kill_at, self.calls = agent, kill_at, 0

    def eval_actions(self, obs, seed=None):
        self.calls += 1
        if self.calls == self.kill_at:
            raise KeyboardInterrupt("killed mid-evaluation")
        return self.agent.eval_actions(obs, seed=seed)


def test_a_killed_evaluation_resumes_at_its_first_unfinished_episode(tmp_path):
    """toy-reach episodes last 25 steps; 6 episodes on 2 envs are 3 batches of 25 policy calls."""
    from d5rl.training.evaluation import EvalProgress, evaluate
    from tests.agents.helpers import make_agent

    agent = make_agent("ddpm_bc", diffusion_steps=3)  # stochastic: each episode's keys must be its own
    unbroken = evaluate(agent, "toy-reach-v0", 6, seed=3, num_envs=2)
    path = tmp_path / "eval_progress.json"
    with pytest.raises(KeyboardInterrupt):
        evaluate(
            _Counting(agent, kill_at=60),
            "toy-reach-v0",
            6,
            seed=3,
            num_envs=2,
            progress=EvalProgress(path, {"step": 7}),
        )
    saved = json.loads(path.read_text())
    assert len(saved["episodes"]) == 4 and saved["evaluation"]["step"] == 7
    again = _Counting(agent)
    resumed = evaluate(again, "toy-reach-v0", 6, seed=3, num_envs=4, progress=EvalProgress(path, {"step": 7}))
    assert again.calls == 25  # episodes 5 and 6 only
    assert resumed == unbroken and not path.exists()


def test_an_evaluation_keeps_the_time_its_finished_episodes_took_before_a_resume(tmp_path, monkeypatch):
    from d5rl.training import evaluation

    clock = [1000.0]
    monkeypatch.setattr(evaluation.time, "monotonic", lambda: clock[0])
    ev, ep = (
        {"task_id": "toy-reach-v0", "seed": 3, "num_episodes": 6, "frame_stack": 1},
        {"return": 1.0, "length": 25, "success": False, "info": {}},
    )
    first = evaluation.EvalProgress(tmp_path / "p.json", {"step": 7})
    assert first.load(ev) == [] and first.earlier_s == 0.0
    clock[0] += 30.0
    first.save(ev, [ep, ep])
    clock[0] += 3600.0  # the machine was off: not the evaluation's time
    second = evaluation.EvalProgress(tmp_path / "p.json", {"step": 7})
    assert len(second.load(ev)) == 2 and second.earlier_s == 30.0
    clock[0] += 5.0
    second.save(ev, [ep] * 4)
    assert json.loads((tmp_path / "p.json").read_text())["wall_s"] == 35.0
    other = evaluation.EvalProgress(tmp_path / "p.json", {"step": 8})  # another evaluation: none of its time
    assert other.load(ev) == [] and other.earlier_s == 0.0


@pytest.mark.parametrize("case", ["other identity", "damaged"])
def test_an_evaluation_does_not_resume_from_another_or_a_damaged_one(tmp_path, case, capsys):
    from d5rl.training.evaluation import EvalProgress, evaluate
    from tests.agents.helpers import make_agent

    agent = make_agent("bc")
    path = tmp_path / "eval_progress.json"
    with pytest.raises(KeyboardInterrupt):
        evaluate(
            _Counting(agent, kill_at=30),
            "toy-reach-v0",
            4,
            seed=3,
            num_envs=2,
            progress=EvalProgress(path, {"step": 7}),
        )
    if case == "damaged":
        path.write_text(path.read_text()[:-20])
    again = _Counting(agent)
    out = evaluate(
        again,
        "toy-reach-v0",
        4,
        seed=3,
        num_envs=2,
        progress=EvalProgress(path, {"step": 8 if case == "other identity" else 7}),
    )
    assert again.calls == 50 and out == evaluate(agent, "toy-reach-v0", 4, seed=3, num_envs=2)
    assert ("is damaged" in capsys.readouterr().err) == (case == "damaged")


def test_a_run_killed_in_its_final_evaluation_resumes_it(tmp_path, monkeypatch, capsys):
    """The loop's evaluator names the step and a hash of the agent's arrays, which a resumed run restores."""
    from d5rl.training.evaluation import EvalProgress

    ds = toy_dataset(10)
    kw = overrides(checkpoint_interval=16, eval_interval=1000, eval_episodes=6, eval_envs=2)
    full = train(resolve("bc", "toy-reach-v0", kw, offline_steps=32, seed=1), tmp_path / "a", dataset=ds)
    real_save = EvalProgress.save

    def save_then_die(self, *a):
        real_save(self, *a)
        raise KeyboardInterrupt("killed after the evaluation's first batch")

    monkeypatch.setattr(EvalProgress, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        train(resolve("bc", "toy-reach-v0", kw, offline_steps=32, seed=1), tmp_path / "b", dataset=ds)
    assert len(json.loads((tmp_path / "b" / "eval_progress.json").read_text())["episodes"]) == 2
    monkeypatch.setattr(EvalProgress, "save", real_save)
    progress = json.loads((tmp_path / "b" / "eval_progress.json").read_text())
    assert progress["wall_s"] > 0  # the first process's time on the two finished episodes
    progress["wall_s"] = 5000.0  # as if they had taken 5,000 s: the resumed run must count them
    (tmp_path / "b" / "eval_progress.json").write_text(json.dumps(progress))
    capsys.readouterr()
    resumed = train(resolve("bc", "toy-reach-v0", kw, offline_steps=32, seed=1), tmp_path / "b", dataset=ds)
    assert "evaluation resumes at episode 3 of 6" in capsys.readouterr().out
    assert 5000.0 < resumed["run_wall_s"] < 5000.0 + full["run_wall_s"] + 600
    drop = ("run_dir", "run_wall_s", "resumed", "agent")
    assert {k: v for k, v in resumed.items() if k not in drop} == {k: v for k, v in full.items() if k not in drop}
    assert rows(tmp_path / "a") == rows(tmp_path / "b") and not (tmp_path / "b" / "eval_progress.json").exists()


def test_a_second_train_into_a_live_run_dir_fails_in_one_line_and_a_finished_run_is_not_evaluated_twice(tmp_path):
    import subprocess
    import sys

    from d5rl.training.loop import RunDirError
    from d5rl.training.rundir import RunDir

    ds, kw = toy_dataset(10), overrides(checkpoint_interval=16, eval_interval=1000, updates_per_call=8)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    # another process holds the run directory (as a live `d5rl train` does for its whole run)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time\n"
            f"fd = os.open({str(RunDir(run_dir).train_lock)!r}, os.O_RDWR | os.O_CREAT)\n"
            "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, f'{os.getpid()}\\n'.encode())\n"
            "print('held', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RunDirError, match=f"another d5rl process \\(pid {holder.pid}\\) is training into"):
            train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=32), run_dir, dataset=ds)
        assert not (run_dir / "checkpoint").exists()
    finally:
        holder.kill()
        holder.wait()
    done = train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=32), run_dir, dataset=ds)
    before = rows(run_dir)
    again = train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=32), run_dir, dataset=ds)
    assert rows(run_dir) == before  # no second final evaluation row
    assert sum(1 for r in before if any(k.startswith("eval/") for k in r)) == 1
    assert again["return"] == done["return"] and again["step"] == 32
    for a, b in zip(leaves(done["agent"]), leaves(again["agent"])):
        np.testing.assert_array_equal(a, b)
