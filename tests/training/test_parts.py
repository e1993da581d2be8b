"""Replay buffer, logger, evaluation and CLI parsers."""

import argparse
import json

import mujoco
import numpy as np

from d5rl.datasets.dataset import mc_tail
from d5rl.envs.kitchen.subtasks import SUBTASK_NAMES, SUBTASKS
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.training.logger import Logger
from d5rl.training.replay import NO_RETURN, ReplayBuffer


def test_replay_buffer_roundtrip_and_mc_returns():
    obs = {"pixels/a": np.zeros((4, 4, 3), np.uint8), "proprio": np.zeros(2, np.float32)}
    buf = ReplayBuffer(obs, 2, capacity=5)
    idx = []
    for t in range(3):
        o = {"pixels/a": np.full((4, 4, 3), t, np.uint8), "proprio": np.full(2, t, np.float32)}
        idx.append(buf.insert(o, np.full(2, t), 1.0, 1.0, o))
    assert buf.data["mc_returns"][0] == NO_RETURN
    buf.set_mc_returns(idx, [1.0, 1.0, 1.0], gamma=0.5)
    np.testing.assert_allclose(buf.data["mc_returns"][:3], [1.75, 1.5, 1.0])
    buf.set_mc_returns(idx, [1.0, 1.0, 1.0], gamma=0.5, bootstrap=mc_tail(1.0, 0.5, terminal=False))  # time limit
    np.testing.assert_allclose(buf.data["mc_returns"][:3], [2.0, 2.0, 2.0])  # 1 / (1 - 0.5) at every step
    for t in range(4):  # wraps around
        buf.insert(obs, np.zeros(2), 0.0, 0.0, obs)
    assert len(buf) == 5 and buf.pos == 2
    b = buf.sample(7, np.random.default_rng(0))
    assert b["observations"]["pixels/a"].shape == (7, 4, 4, 3) and b["actions"].shape == (7, 2)
    other = ReplayBuffer(obs, 2, capacity=5)
    other.load_state_dict(buf.state_dict())
    b2 = other.sample(7, np.random.default_rng(0))
    for k in ("actions", "rewards", "masks"):
        np.testing.assert_array_equal(b[k], b2[k])
    np.testing.assert_array_equal(b["observations"]["pixels/a"], b2["observations"]["pixels/a"])


def test_logger_grows_columns_and_truncates(tmp_path):
    log = Logger(tmp_path, tensorboard=False)
    log.log(10, {"a": 1.0})
    log.log(20, {"a": 2.0, "b": float("nan")})
    log.log(30, {"a": 3.0})
    header = (tmp_path / "metrics.csv").read_text().splitlines()[0]
    assert header == "step,a,b"
    log2 = Logger(tmp_path, tensorboard=False)
    log2.truncate_after(20)
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["step"] for x in lines] == [10, 20]
    assert json.loads(lines[1])["b"] == "nan"
    assert len((tmp_path / "metrics.csv").read_text().splitlines()) == 3


def test_evaluation_does_not_depend_on_env_count():
    # what lets eval_envs / eval_processes be execution-only settings (d5rl.training.config.EXECUTION_KEYS)
    from d5rl.training.evaluation import evaluate
    from tests.agents.helpers import make_agent

    agent = make_agent("bc")
    one = evaluate(agent, "toy-reach-v0", 4, seed=3, num_envs=1)
    four = evaluate(agent, "toy-reach-v0", 4, seed=3, num_envs=4)
    two_processes = evaluate(agent, "toy-reach-v0", 4, seed=3, num_envs=2, processes=True)
    np.testing.assert_allclose(one["returns"], four["returns"], rtol=1e-6)
    np.testing.assert_allclose(one["returns"], two_processes["returns"], rtol=1e-6)
    assert one["length"] == 25 and 0 <= one["success"] <= 1


def test_stochastic_evaluation_does_not_depend_on_env_count():
    """A diffusion policy samples its actions: each episode draws its own keys, whatever steps beside it."""
    from d5rl.training.evaluation import evaluate
    from tests.agents.helpers import make_agent

    agent = make_agent("ddpm_bc", diffusion_steps=3)
    one = evaluate(agent, "toy-reach-v0", 3, seed=3, num_envs=1)
    three = evaluate(agent, "toy-reach-v0", 3, seed=3, num_envs=3)
    np.testing.assert_allclose(one["returns"], three["returns"], rtol=1e-5)
    other = evaluate(agent, "toy-reach-v0", 3, seed=4, num_envs=3)  # other episodes: not the same numbers
    assert not np.allclose(one["returns"], other["returns"])


def test_cli_parsers(tmp_path, capsys):
    from d5rl.runner.train_cli import add_eval_parser, add_train_parser

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    add_train_parser(sub)
    add_eval_parser(sub)
    args = parser.parse_args(
        ["train", "iql", "toy-reach-v0", "--set", "expectile=0.9", "--set", "eval_interval=5", "--show-config"]
    )
    assert args.func(args) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["agent"]["expectile"] == 0.9 and shown["train"]["eval_interval"] == 5
    args = parser.parse_args(["eval", str(tmp_path), "--episodes", "3"])
    assert args.episodes == 3 and args.func.__name__ == "cmd_eval"


def test_evaluation_scores_info_scored_tasks_from_the_last_info():
    """Kitchen and WidowX score from info['score'] at the episode's end, not from the return."""
    import d5rl
    from d5rl.training.evaluation import evaluate

    class Still:
        def eval_actions(self, obs, seed=None):
            return np.zeros((len(obs["proprio"]), 5), np.float32)

    out = evaluate(Still(), "wx-sorting-v0", 1, seed=5)
    env = d5rl.make_env("wx-sorting-v0")
    env.reset(seed=5)
    total, done = 0.0, False
    while not done:
        _, r, term, trunc, info = env.step(np.zeros(5, np.float32))
        total, done = total + r, term or trunc
    assert out["returns"] == [total]
    assert out["score"] == d5rl.episode_score("wx-sorting-v0", total, info) == info["score"]


class _MicrowaveOpenOnSeed8(KitchenEnv):
    """A 3-step kitchen episode; the one reset with seed 8 starts with the microwave open."""

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        if seed == 8:
            sub = SUBTASKS["microwave"]
            self.data.qpos[sub.qpos_indices(self.model)] = sub.goal
            mujoco.mj_forward(self.model, self.data)
        return obs, info


def _short_kitchen():
    from gymnasium.wrappers import TimeLimit

    return TimeLimit(_MicrowaveOpenOnSeed8(obs_mode="state"), 3)


def test_evaluation_averages_the_tasks_episode_stats():
    """The kitchen reports which subtasks an episode did; evaluation averages them, in one process or many."""
    from d5rl.training.evaluation import evaluate

    class Still:
        def eval_actions(self, obs, seed=None):
            return np.zeros((len(obs), 9), np.float32)

    for processes in (False, True):
        out = evaluate(
            Still(),
            "kitchen-standard-mixed-state-v0",
            2,
            seed=7,
            num_envs=2,
            processes=processes,
            env_fn=_short_kitchen,
        )
        assert out["stats"]["subtask/microwave"] == 0.5, processes  # episodes reset with seeds 7 and 8
        assert out["stats"]["subtask/kettle"] == 0.0 and len(out["stats"]) == len(SUBTASK_NAMES)


def test_replay_buffer_next_actions_stay_within_episodes():
    buf = ReplayBuffer(np.zeros(2, np.float32), 1, capacity=10)
    obs = np.zeros(2, np.float32)
    for episode in ((1.0, 2.0, 3.0), (7.0, 8.0)):
        for a in episode:
            buf.insert(obs, np.array([a]), 0.0, 1.0, obs)
        buf.end_episode()
    np.testing.assert_array_equal(buf.data["next_actions"][:5, 0], [2, 3, 3, 8, 8])  # the last step repeats its own


def test_prefetched_batches_are_the_sequential_ones():
    """Gathering ahead in threads changes nothing a run sees: the same batches in the same order, and the
    run's generator after each batch in the state a plain ``sample`` leaves it (what checkpoints save)."""
    from d5rl.production.toy.data import toy_dataset
    from d5rl.training.parts import Prefetcher, Sampler

    sampler = Sampler(toy_dataset(6, pixels=True), 3, ("mc_returns",), 0.9)
    plain, ahead = np.random.default_rng(5), np.random.default_rng(5)
    with Prefetcher(sampler, 16, ahead, threads=3, depth=4) as batches:
        for _ in range(7):
            want, got = sampler.sample(16, plain), batches.next()
            assert ahead.bit_generator.state == plain.bit_generator.state
            assert got["observations"]["pixels/front"].shape == (16, 16, 16, 9)  # 3 stacked RGB frames
            for key in ("observations", "next_observations"):
                for part in want[key]:
                    np.testing.assert_array_equal(np.asarray(got[key][part]), want[key][part])
            for key in ("actions", "rewards", "masks", "mc_returns"):
                np.testing.assert_array_equal(np.asarray(got[key]), want[key])


def test_a_failed_prefetch_raises_in_the_training_thread():
    import pytest

    from d5rl.production.toy.data import toy_dataset
    from d5rl.training.parts import Prefetcher, Sampler

    class Broken(Sampler):
        def sample(self, n, rng, indices=None):
            raise OSError("disk went away")

    with Prefetcher(Broken(toy_dataset(2, pixels=True), 3, (), 0.9), 4, np.random.default_rng(0)) as batches:
        with pytest.raises(OSError, match="disk went away"):
            batches.next()


def test_run_state_counts_wall_time_over_resumed_processes(monkeypatch):
    """A checkpoint carries the run's elapsed wall time; a resumed run goes on counting from it."""
    from d5rl.training import parts

    clock = [1000.0]
    monkeypatch.setattr(parts.time, "monotonic", lambda: clock[0])
    first = parts.RunState(np.random.default_rng(0))
    clock[0] += 60.0
    saved = json.loads(json.dumps(first.to_json()))
    assert saved["elapsed_s"] == 60.0
    clock[0] += 3600.0  # the machine was off: not the run's time
    resumed = parts.RunState.from_json(saved)
    clock[0] += 15.0
    assert resumed.elapsed() == 75.0
    del saved["elapsed_s"]  # a checkpoint written before runs added up the time of earlier processes
    assert parts.RunState.from_json(saved).elapsed() == 0.0
