"""One source of per-task settings, one resolver: train, bench, --show-config and eval agree."""

import json
import re

import pytest

pytest.importorskip("jax")

import d5rl
from d5rl.agents import AGENTS, get_agent
from d5rl.cli import main
from d5rl.runner import jobs
from d5rl.runner.grid import expand_grid, parse_assignments
from d5rl.settings import resolve, run_steps, table
from d5rl.training.config import get_train_config

TASKS = [t for t in d5rl.list_tasks() if not t.startswith("test-")]


def _plain(d):
    return {k: v for k, v in d.items() if not k.startswith("_")}


def test_every_setting_is_a_key_of_its_agent_or_the_loop():
    data = table()
    sections = [("observations", obs, sec) for obs, sec in _plain(data["observations"]).items()]
    sections += [
        (group, obs, sec) for group, by_obs in _plain(data["groups"]).items() for obs, sec in _plain(by_obs).items()
    ]
    for where, obs, section in sections:
        assert obs in ("state", "pixels"), (where, obs)
        for algo, values in _plain(section).items():
            names = list(AGENTS) if algo == "all" else [algo]
            assert algo == "all" or algo in AGENTS, f"{where}/{obs}: unknown algorithm {algo}"
            for name in names:
                config = get_agent(name)[1]()
                for key, value in _plain(values).items():
                    if algo == "all" and key not in config:
                        continue  # "all" applies the keys an agent has
                    assert key in config, f"{where}/{obs}/{algo}: {key} is not a key of {name}'s config"
                    assert config.override({key: value})[key] == value
    loop = get_train_config()
    for group, values in _plain(data["protocol"]).items():
        for key in _plain(values):
            assert key in loop, f"protocol {group}: {key} is not a training-loop key"
    assert data["sweeps"]["iql"]["expectile"] == [0.5, 0.7, 0.9, 0.95]
    assert data["sweeps"]["cql"]["cql_alpha"] == [0.1, 1.0, 5.0, 10.0]


# How a source starts: the D5RL paper's appendix C, a file of the authors' release, another paper, a pointer
# to the entry whose values it repeats, or d5rl's own reason.
CITATION = re.compile(
    r"^(paper App\. C, \S|release (examples|jaxrl2)/\S+\.(py|sh)|(IQL|TD3\+BC|RLPD) paper \("
    r"|as \S|d5rl( takes|:) \S)"
)


def test_every_entry_cites_a_checkable_source():
    """Every entry that sets values says where each comes from, precisely enough to check: a paper section or
    table, or a release file and key ("; " separates citations; docs/agents.md sets them side by side)."""
    data = table()
    entries = [
        (f"{group}/{obs}/{algo}", values)
        for group, by_obs in _plain(data["groups"]).items()
        for obs, sec in _plain(by_obs).items()
        for algo, values in _plain(sec).items()
    ]
    entries += [
        (f"observations/{obs}/{algo}", values)
        for obs, sec in _plain(data["observations"]).items()
        for algo, values in _plain(sec).items()
    ]
    entries += [(f"protocol/{group}", values) for group, values in _plain(data["protocol"]).items()]
    assert len(entries) > 40
    for where, values in entries:
        source = values.get("_source", "")
        assert isinstance(source, str) and source.strip(), f"{where} has no _source"
        for part in source.split("; "):
            assert CITATION.match(part), f"{where}: {part!r} names no paper section, release file or reason"
    text = json.dumps(data)
    for claim in (
        "release IQL config",
        "release config",
        "release expectile 0.7",
        "0.7 is its config default",
        "swept 0.05-10",
        "release CQL config default",
    ):  # claims an outside review found false
        assert claim not in text, claim


def test_train_bench_and_show_config_agree_for_every_task_and_algorithm(capsys, monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr("d5rl.training.loop.train", lambda *a, **k: calls.append((a, k)) or {})
    for task in TASKS:
        for algo in AGENTS:
            offline, online = run_steps(algo, 10_000, 0)
            assert main(["train", algo, task, "--offline-steps", "10000", "--show-config"]) == 0
            shown = json.loads(capsys.readouterr().out)
            [cell] = expand_grid([task], [algo], [0], 10_000, 0)
            calls.clear()
            jobs.train_job(cell, tmp_path)
            (a_algo, a_task, a_off, a_on, _, overrides, _), kw = calls[0]
            in_bench = resolve(a_algo, a_task, overrides, offline_steps=a_off, online_steps=a_on, tuned=kw["tuned"])
            direct = resolve(algo, task, offline_steps=offline, online_steps=online)
            assert shown["agent"] == direct.agent.to_dict() == in_bench.agent.to_dict(), (task, algo)
            # the bench only adds its own progress flag to the loop's settings
            assert {**shown["train"], "progress": False} == in_bench.train.to_dict(), (task, algo)


def test_what_the_settings_say():
    pix = resolve("iql", "kitchen-standard-mixed-v0")
    state = resolve("iql", "kitchen-standard-mixed-state-v0")
    assert (pix.agent.batch_size, pix.agent.actor_lr, pix.agent.temperature, pix.train.frame_stack) == (
        64,
        1e-4,
        3.0,
        3,
    )
    assert pix.agent.expectile == 0.5  # the release's kitchen IQL config
    wx = resolve("iql", "wx-sorting-v0")
    assert (wx.agent.expectile, wx.agent.temperature, wx.train.frame_stack) == (0.9, 10.0, 1)  # release WidowX
    assert resolve("ddpm_bc", "wx-sorting-v0").agent.actor_lr == 3e-4  # the paper's 1e-4 is IQL's and CQL's
    a1 = resolve("bc", "a1-walk-v0", offline_steps=100).agent
    assert (a1.actor_lr, a1.dropout_rate, a1.actor_decay_steps, a1.learned_std) == (1e-3, 0.1, 200, False)
    assert resolve("bc", "wx-sorting-v0").agent.actor_decay_steps == 0  # the release's WidowX BC: constant lr
    assert (state.agent.batch_size, state.agent.temperature, state.train.frame_stack) == (256, 0.5, 1)
    assert pix.train.eval_episodes == 50 and pix.train.eval_interval == 10_000
    assert resolve("bc", "a1-walk-v0").agent.actor_lr == 1e-3
    assert resolve("cql", "wx-sorting-v0").agent.cql_alpha == 0.1
    assert resolve("bc", "toy-reach-pixels-v0").agent.batch_size == 64  # every pixel agent: the paper's batch
    plain = resolve("iql", "kitchen-standard-mixed-v0", tuned=False)
    assert plain.agent.batch_size == 256 and plain.train.eval_episodes == get_train_config().eval_episodes
    assert resolve("iql", "a1-walk-v0", offline_steps=100).agent.actor_decay_steps == 100
    assert resolve("iql", "a1-walk-v0", offline_steps=100, online_steps=5).agent.actor_decay_steps == 0


def test_user_values_beat_the_settings_and_are_parsed_by_type():
    over = parse_assignments(["expectile=0.9", "eval_episodes=3"])
    assert over == {"expectile": "0.9", "eval_episodes": "3"}
    r = resolve("iql", "wx-sorting-v0", over)
    assert r.agent.expectile == 0.9 and r.train.eval_episodes == 3 and r.agent.batch_size == 64
    from d5rl.agents.config import ConfigError

    with pytest.raises(ConfigError, match="expectile"):
        resolve("iql", "wx-sorting-v0", {"expectile": "high"})


def test_rlpd_takes_no_offline_steps_before_fine_tuning(capsys):
    [rlpd, iql] = expand_grid(["a1-walk-v0"], ["rlpd", "iql"], [0], 500_000, 500_000)
    assert (rlpd.offline_steps, rlpd.online_steps) == (0, 500_000)
    assert (iql.offline_steps, iql.online_steps) == (500_000, 500_000)
    [offline_only] = expand_grid(["a1-walk-v0"], ["rlpd"], [0], 10_000, 0)
    assert offline_only.offline_steps == 10_000  # Table 1 runs RLPD on the data alone
    assert (
        main(["train", "rlpd", "a1-walk-v0", "--offline-steps", "1000", "--online-steps", "50", "--show-config"]) == 0
    )
    out = capsys.readouterr()
    assert json.loads(out.out)["offline_steps"] == 0 and "no offline phase" in out.err


def test_a_run_records_the_resolved_config_that_eval_reads(tmp_path):
    from d5rl.envs.toy.data import toy_dataset
    from d5rl.training.loop import load_run, train

    over = ["hidden_dims=16,16", "eval_episodes=1", "eval_envs=1", "progress=false", "tensorboard=false"]
    train("iql", "toy-reach-v0", 16, 0, 0, over, tmp_path / "run", dataset=toy_dataset(4))
    written = json.loads((tmp_path / "run" / "config.json").read_text())
    want = resolve("iql", "toy-reach-v0", over, offline_steps=16)
    assert written["agent"] == want.agent.to_dict() and written["train"] == want.train.to_dict()
    _, resolved = load_run(tmp_path / "run")  # what `d5rl eval` uses
    assert resolved["train"]["frame_stack"] == want.train.frame_stack == 1
    assert written["agent_version"] == 1
    (tmp_path / "run" / "config.json").write_text(json.dumps({**written, "agent_version": 0}))
    from d5rl.training.loop import RunDirError

    with pytest.raises(RunDirError, match="trained by iql v0; this d5rl's is v1"):  # another version's networks
        load_run(tmp_path / "run")
