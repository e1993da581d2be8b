"""The training loop: run directory contents, exact resume after a kill, NaN detection, overrides."""

import json

import numpy as np
import pytest

from d5rl.agents.config import ConfigError
from d5rl.production.toy.data import toy_dataset
from d5rl.settings import resolve
from d5rl.training.loop import NonFiniteLossError, load_run, train
from tests.training.helpers import leaves, overrides


def test_offline_run_writes_everything(tmp_path):
    ds = toy_dataset(20)
    res = train(
        resolve("iql", "toy-reach-v0", overrides(eval_interval=32, checkpoint_interval=32), offline_steps=64),
        tmp_path / "run",
        dataset=ds,
    )
    run = tmp_path / "run"
    for name in (
        "config.json",
        "metrics.jsonl",
        "metrics.csv",
        "summary.json",
        "checkpoint/manifest.json",
        "checkpoint/agent.msgpack",
        "checkpoint/state.json",
    ):
        assert (run / name).exists(), name
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["agent"]["hidden_dims"] == [32, 32] and cfg["train"]["frame_stack"] == 1
    assert cfg["agent"]["actor_decay_steps"] == 64  # IQL's policy lr decays over an offline-only run
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert "critic/loss" in header and "eval/toy-reach-v0/score" in header and "time/updates_per_s" in header
    assert res["step"] == 64 and np.isfinite(res["score"])
    agent, resolved = load_run(run)
    for a, b in zip(leaves(agent), leaves(res["agent"])):
        np.testing.assert_array_equal(a, b)


def test_nan_rewards_stop_the_run(tmp_path):
    ds = toy_dataset(10)
    ds.arrays["rewards"] = np.full_like(ds.arrays["rewards"], np.nan)
    with pytest.raises(NonFiniteLossError, match="critic/loss") as e:
        train(resolve("iql", "toy-reach-v0", overrides(), offline_steps=32), tmp_path / "n", dataset=ds)
    assert e.value.hint


def test_overrides_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="unknown config key"):
        train(resolve("bc", "toy-reach-v0", ["no_such_key=1"], offline_steps=8), tmp_path / "o", dataset=toy_dataset(5))
    with pytest.raises(ConfigError):
        train(
            resolve("bc", "toy-reach-v0", ["batch_size=big"], offline_steps=8), tmp_path / "o", dataset=toy_dataset(5)
        )


def test_other_run_in_directory_is_refused(tmp_path):
    from d5rl.training.loop import RunDirError

    ds = toy_dataset(5)
    train(resolve("bc", "toy-reach-v0", overrides(), offline_steps=8), tmp_path / "r", dataset=ds)
    with pytest.raises(RunDirError):
        train(resolve("bc", "toy-reach-v0", overrides(actor_lr=1e-3), offline_steps=8), tmp_path / "r", dataset=ds)


def test_td3bc_run_normalizes_states_with_the_dataset_statistics(tmp_path):
    ds = toy_dataset(20)
    train(resolve("td3bc", "toy-reach-v0", overrides(), offline_steps=16), tmp_path / "t", dataset=ds)
    agent_cfg = json.loads((tmp_path / "t" / "config.json").read_text())["agent"]
    obs = np.asarray(ds.observations, np.float64)
    np.testing.assert_allclose(agent_cfg["obs_mean"], obs.mean(0), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(agent_cfg["obs_std"], obs.std(0) + 1e-3, rtol=1e-6)
    agent, _ = load_run(tmp_path / "t")
    assert agent.config.obs_mean == tuple(agent_cfg["obs_mean"])


@pytest.mark.parametrize("algo", ["fql", "rebrac"])
def test_modern_baselines_train_offline_then_online_from_the_cli(tmp_path, capsys, algo):
    from d5rl.cli import main

    small = ["actor_hidden_dims=16,16", "critic_hidden_dims=16,16"] if algo == "fql" else ["hidden_dims=16,16"]
    args = [
        "train",
        algo,
        "toy-reach-v0",
        "--offline-steps",
        "16",
        "--online-steps",
        "30",
        "--run-dir",
        str(tmp_path / "run"),
    ]
    for s in small + ["batch_size=16", "eval_episodes=2", "eval_envs=2", "progress=false", "tensorboard=false"]:
        args += ["--set", s]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["step"] == 46 and np.isfinite(summary["score"])
    rows = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert any("train/episode_return" in r for r in rows)  # the online phase ran (with next actions in the buffer)


def test_the_run_records_the_dataset_it_trains_on(tmp_path):
    import d5rl
    from d5rl.datasets.generation import data_identity
    from d5rl.training.loop import RunDirError

    ds = d5rl.load_dataset("toy-reach-v0", episodes=6)
    train(resolve("bc", "toy-reach-v0", overrides(), offline_steps=8), tmp_path / "r", dataset=ds)
    recorded = json.loads((tmp_path / "r" / "config.json").read_text())["dataset"]
    assert recorded == {**data_identity("toy-reach-v0"), "episodes": 6}
    # the same directory resumed on other data is another run
    ds.metadata["dataset_version"] = recorded["dataset_version"] + 1
    with pytest.raises(RunDirError, match="trained on other data"):
        train(resolve("bc", "toy-reach-v0", overrides(), offline_steps=8), tmp_path / "r", dataset=ds)
    # in-memory data (no generated dataset behind it) records nothing
    train(resolve("bc", "toy-reach-v0", overrides(), offline_steps=8), tmp_path / "m", dataset=toy_dataset(5))
    assert "dataset" not in json.loads((tmp_path / "m" / "config.json").read_text())


@pytest.mark.parametrize(
    "setting", ["hidden_dims=1000000000", "batch_size=1000000000", "hidden_dims=100000,100000,100000"]
)
def test_networks_or_batches_too_big_for_memory_fail_in_one_line_before_anything_is_written(tmp_path, setting):
    from d5rl.agents.config import ConfigError
    from d5rl.training.memory import available_memory

    assert available_memory() is not None
    with pytest.raises(ConfigError, match=r"need at least [\d,.]+ GiB; [\d,.]+ GiB are available") as e:
        train(
            resolve("td3bc", "toy-reach-v0", overrides(**dict([setting.split("=")])), offline_steps=8),
            tmp_path / "run",
            dataset=toy_dataset(4),
        )
    assert "\n" not in str(e.value)
    assert not (tmp_path / "run").exists()


def test_the_memory_floor_counts_each_network_once_as_float32_with_adam():
    from d5rl.agents.config import Config
    from d5rl.training.memory import memory_floor

    example = {"observations": np.zeros((1, 3), np.float32), "actions": np.zeros((1, 2), np.float32)}
    cfg = Config({"batch_size": 10, "hidden_dims": (4, 5)})
    widths = [3 + 2, 4, 5, 1]
    params = (5 * 4 + 4) + (4 * 5 + 5) + (5 * 1 + 1)
    assert memory_floor(cfg, example) == 10 * 4 * 2 * 5 + 16 * params + 4 * 10 * max(widths)


def test_a_full_disk_under_the_run_dir_is_named_as_the_run_dirs(tmp_path, monkeypatch):
    import errno

    from d5rl.errors import D5RLError
    from d5rl.training import loop

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(loop, "_write_config", full)  # the run's first write
    with pytest.raises(D5RLError, match=f"the disk holding {tmp_path / 'run'} is full") as e:
        train(resolve("td3bc", "toy-reach-v0", overrides(), offline_steps=8), tmp_path / "run", dataset=toy_dataset(4))
    assert "--run-dir" in e.value.hint and "D5RL_HOME" not in e.value.hint


@pytest.mark.parametrize(
    "content, match",
    [
        ("fifo", "is a FIFO, not a regular file"),
        ('{"step": 1}\n{"step": 2\n', "line 2 is not a metrics row"),
        ('{"step": "1"}\n', "line 1 is not a metrics row"),
    ],
)
def test_a_damaged_metrics_log_is_a_one_line_error(tmp_path, content, match):
    import os

    from d5rl.errors import D5RLError
    from d5rl.training.logger import Logger

    path = tmp_path / "metrics.jsonl"
    if content == "fifo":
        os.mkfifo(path)  # reading it would wait for a writer forever
    else:
        path.write_text(content)
    with pytest.raises(D5RLError, match=match):
        Logger(tmp_path, tensorboard=False)


def test_an_evaluation_progress_file_that_is_a_fifo_is_ignored_with_a_warning(tmp_path, capsys):
    import os

    from d5rl.training.evaluation import EvalProgress

    os.mkfifo(tmp_path / "eval_progress.json")
    progress = EvalProgress(tmp_path / "eval_progress.json", {"step": 1})
    assert progress.load({"num_episodes": 2}) == []
    assert "is damaged (D5RLError); the evaluation starts at episode 1" in capsys.readouterr().err
