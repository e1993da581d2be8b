"""One source of per-task settings, one resolver: train, bench, --show-config and eval agree."""

import dataclasses
import json
import re

import pytest

pytest.importorskip("jax")

import d5rl
from d5rl import settings
from d5rl.agents import AGENTS, get_agent
from d5rl.cli import main
from d5rl.runner import jobs
from d5rl.runner.grid import expand_grid, parse_assignments
from d5rl.settings import resolve, table
from d5rl.training import loop
from d5rl.training.config import RunSpec, get_train_config

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


def test_train_bench_and_show_config_pass_the_same_run_spec_for_every_task_and_algorithm(capsys, monkeypatch, tmp_path):
    """`d5rl train` and a bench cell hand the trainer a run spec; --show-config prints the one `d5rl train` would
    hand it.  The bench cell's differs only by its progress flag (the grid shows its own)."""
    specs = []
    monkeypatch.setattr("d5rl.training.loop.train", lambda spec, run_dir=None, **k: specs.append(spec) or {})
    for task in TASKS:
        for algo in AGENTS:
            assert main(["train", algo, task, "--offline-steps", "10000", "--show-config"]) == 0
            shown = json.loads(capsys.readouterr().out)
            specs.clear()
            assert main(["train", algo, task, "--offline-steps", "10000", "--run-dir", str(tmp_path / "r")]) == 0
            capsys.readouterr()
            [cell] = expand_grid([task], [algo], [0], 10_000, 0)
            jobs.train_job(cell, tmp_path)
            in_train, in_bench = specs
            assert isinstance(in_train, RunSpec) and isinstance(in_bench, RunSpec)
            assert shown == in_train.to_json(), (task, algo)
            assert in_bench == dataclasses.replace(in_train, train=in_train.train.replace(progress=False)), (task, algo)


def test_settings_are_resolved_once_per_d5rl_train(monkeypatch, tmp_path, capsys):
    """One resolution per command, whichever way the code reaches the resolver: every call of ``resolve`` goes
    through ``layers`` (tuned runs), and the spec the trainer gets is the one ``resolve`` returned."""
    from d5rl.production.toy.data import toy_dataset

    returned, layered = [], []
    real_resolve, real_layers = settings.resolve, settings.layers
    monkeypatch.setattr(settings, "resolve", lambda *a, **k: returned.append(real_resolve(*a, **k)) or returned[-1])
    monkeypatch.setattr(settings, "layers", lambda *a, **k: layered.append(a) or real_layers(*a, **k))
    monkeypatch.setattr("d5rl.training.loop.load_task_dataset", lambda task, **kw: toy_dataset(4))
    trained = []
    real_train = loop.train
    monkeypatch.setattr(loop, "train", lambda spec, *a, **k: trained.append(spec) or real_train(spec, *a, **k))
    argv = ["train", "bc", "toy-reach-v0", "--offline-steps", "8", "--seed", "3", "--run-dir", str(tmp_path / "r")]
    argv += ["--set", "hidden_dims=16,16", "--set", "eval_episodes=1", "--set", "tensorboard=false"]
    assert main(argv) == 0
    assert len(returned) == len(layered) == 1 and trained == returned
    assert trained[0].seed == 3 and json.loads(capsys.readouterr().out)["step"] == 8
    written = json.loads((tmp_path / "r" / "config.json").read_text())
    assert {k: written[k] for k in ("algo", "task_id", "seed", "train")} == {
        k: trained[0].to_json()[k] for k in ("algo", "task_id", "seed", "train")
    }
    returned.clear(), layered.clear()
    assert main(["train", "bc", "toy-reach-v0", "--offline-steps", "8", "--show-config"]) == 0
    assert len(returned) == len(layered) == 1


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
    from d5rl.production.toy.data import toy_dataset
    from d5rl.training.loop import load_run, train

    over = ["hidden_dims=16,16", "eval_episodes=1", "eval_envs=1", "progress=false", "tensorboard=false"]
    train(resolve("iql", "toy-reach-v0", over, offline_steps=16), tmp_path / "run", dataset=toy_dataset(4))
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


def test_frame_stack_on_a_state_task_is_refused_not_ignored(capsys):
    """Only camera frames are stacked: a state task asked for 3 would train on one state silently."""
    assert resolve("bc", "kitchen-standard-mixed-v0", ["frame_stack=2"]).train.frame_stack == 2
    with pytest.raises(d5rl.D5RLError, match="observes states"):
        resolve("bc", "kitchen-standard-mixed-state-v0", ["frame_stack=3"])
    assert resolve("bc", "kitchen-standard-mixed-state-v0", ["frame_stack=1"]).train.frame_stack == 1
    assert main(["train", "bc", "a1-walk-v0", "--set", "frame_stack=3", "--show-config"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: frame_stack=3: a1-walk-v0 observes states") and "Traceback" not in err
