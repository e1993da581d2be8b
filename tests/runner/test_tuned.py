"""The tuned-settings file: valid keys, family matching, layering with --set."""

import json

import pytest

from d5rl.runner.grid import TUNED_PATH, expand_grid, family_key, parse_assignments, tuned_settings

TUNED = json.loads(TUNED_PATH.read_text())


def _plain(d):
    return {k: v for k, v in d.items() if not k.startswith("_")}


def test_every_tuned_key_is_an_agent_config_key():
    pytest.importorskip("jax")
    from d5rl.agents import AGENTS, get_agent

    for family, algos in _plain(TUNED["tuned"]).items():
        for algo, values in _plain(algos).items():
            assert algo in AGENTS, f"{family}: unknown algorithm {algo}"
            config = get_agent(algo)[1]()
            for key, value in _plain(values).items():
                assert key in config, f"{family}/{algo}: {key} is not a key of {algo}'s get_config()"
                assert config.override({key: value})[key] == value
    for algo, grid in _plain(TUNED["sweeps"]).items():
        config = get_agent(algo)[1]()
        for key in grid:
            assert key in config


def test_protocol_keys_are_training_loop_keys():
    pytest.importorskip("jax")
    from d5rl.training.loop import get_train_config

    cfg = get_train_config()
    for family, values in _plain(TUNED["protocol"]).items():
        for key in _plain(values):
            assert key in cfg, f"protocol {family}: {key} is not a training-loop key"


def test_paper_sweep_grids():
    assert TUNED["sweeps"]["iql"]["expectile"] == [0.5, 0.7, 0.9, 0.95]
    assert TUNED["sweeps"]["cql"]["cql_alpha"] == [0.1, 1.0, 5.0, 10.0]
    assert TUNED["sweeps"]["calql"]["cql_alpha"] == [0.1, 1.0, 5.0, 10.0]


def test_family_matching_takes_the_longest_dash_prefix():
    table = {"kitchen": 1, "kitchen-standard": 2, "a1": 3, "_comment": 4}
    assert family_key("kitchen-standard-mixed-v0", table) == "kitchen-standard"
    assert family_key("kitchen-randomized-demos-v0", table) == "kitchen"
    assert family_key("a1-walk-v0", table) == "a1"
    assert family_key("a10-walk-v0", table) is None  # prefixes end at a dash
    assert family_key("wx-sorting-v0", table) is None


def test_registered_benchmark_tasks_get_tuned_settings():
    from d5rl.registry import list_tasks

    tasks = [t for t in list_tasks() if t.split("-")[0] in ("a1", "kitchen", "wx")]
    if not tasks:
        pytest.skip("no benchmark task registered yet")
    for t in tasks:
        overrides, protocol = tuned_settings(t, "iql")
        assert "expectile" in overrides and protocol["eval_episodes"] > 0, t
    over, proto = tuned_settings("kitchen-standard-mixed-v0", "CQL")
    assert over["cql_alpha"] == 5.0 and over["batch_size"] == 64 and proto == {"eval_interval": 10000,
                                                                               "eval_episodes": 50}


def test_user_overrides_beat_tuned_values():
    [cell] = expand_grid(["wx-sorting-v0"], ["IQL"], [3], 10, 0, overrides=parse_assignments(["expectile=0.9"]))
    assert cell.algo == "iql" and cell.overrides["expectile"] == 0.9 and cell.overrides["batch_size"] == 64
    [plain] = expand_grid(["wx-sorting-v0"], ["td3+bc"], [0], 10, 0, tuned=False)
    assert plain.algo == "td3bc" and plain.overrides == {} and plain.protocol == {}
    assert parse_assignments(["hidden_dims=[512,512]", "name=abc"]) == {"hidden_dims": [512, 512], "name": "abc"}
