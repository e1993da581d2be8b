"""Checkpoints never run code, are checked on load, and fall back to the previous one when damaged."""

import json
import os
import pickle
import subprocess
import sys

import jax
import numpy as np
import pytest

from d5rl.datasets.dataset import Dataset
from d5rl.production.toy.data import toy_dataset
from d5rl.settings import resolve
from d5rl.training.checkpoint import Checkpoint, CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from d5rl.training.loop import load_run, train
from tests.training.helpers import interrupt_after_checkpoint

SMALL = [
    "hidden_dims=32,32",
    "batch_size=32",
    "eval_episodes=2",
    "eval_envs=2",
    "log_interval=16",
    "progress=false",
    "tensorboard=false",
    "eval_interval=1000",
    "updates_per_call=8",
]


class _Payload:
    """Unpickling this creates a marker file: what a crafted checkpoint would do with os.system."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def _leaves(agent):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(agent)]


def _flip_byte(path, offset=None):
    data = bytearray(path.read_bytes())
    i = len(data) // 2 if offset is None else offset
    data[i] ^= 0x01
    path.write_bytes(bytes(data))


def test_round_trip_keeps_previous(tmp_path):
    buf = {"obs/": np.arange(6, dtype=np.float32).reshape(3, 2), "meta": np.array([3, 0, 8])}
    save_checkpoint(tmp_path, Checkpoint(b"agent-1", {"step": 1, "rng": {"s": 2**100}}))
    save_checkpoint(tmp_path, Checkpoint(b"agent-2", {"step": 2}, buf))
    latest = load_checkpoint(tmp_path)
    assert latest.agent == b"agent-2" and latest.state == {"step": 2}
    np.testing.assert_array_equal(latest.buffer["obs/"], buf["obs/"])
    prev = read_checkpoint(tmp_path / "checkpoint.prev")
    assert prev.agent == b"agent-1" and prev.state["rng"]["s"] == 2**100 and prev.buffer is None
    assert not list(tmp_path.glob(".checkpoint.tmp-*"))


def test_flipped_byte_falls_back_to_previous_with_one_line_warning(tmp_path):
    save_checkpoint(tmp_path, Checkpoint(b"agent-1", {"step": 1}))
    save_checkpoint(tmp_path, Checkpoint(b"agent-2", {"step": 2}))
    _flip_byte(tmp_path / "checkpoint" / "agent.msgpack", 0)
    warnings = []
    ckpt = load_checkpoint(tmp_path, warn=warnings.append)
    assert ckpt.state == {"step": 1} and ckpt.agent == b"agent-1"
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert "agent.msgpack is damaged" in warnings[0] and "checkpoint.prev" in warnings[0]


@pytest.mark.parametrize("damage", ["truncate", "flip", "no_manifest", "format"])
def test_unusable_checkpoints_get_an_error_naming_the_file(tmp_path, damage):
    save_checkpoint(tmp_path, Checkpoint(b"agent-1" * 100, {"step": 1}))
    d = tmp_path / "checkpoint"
    if damage == "truncate":
        (d / "agent.msgpack").write_bytes((d / "agent.msgpack").read_bytes()[:50])
    elif damage == "flip":
        _flip_byte(d / "state.json")
    elif damage == "no_manifest":
        (d / "manifest.json").unlink()
    else:
        m = json.loads((d / "manifest.json").read_text())
        m["format_version"] = 99
        (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CheckpointError) as e:
        load_checkpoint(tmp_path)
    assert str(d) in e.value.message and "\n" not in e.value.message


def _write_pickle_checkpoint(d, marker):
    d.mkdir(parents=True, exist_ok=True)
    (d / "state.pkl").write_bytes(pickle.dumps({"step": 0, "agent": _Payload(marker)}))


def test_crafted_pickle_is_never_opened_by_train_or_eval(tmp_path):
    ds = toy_dataset(10)
    run = tmp_path / "run"
    train(resolve("bc", "toy-reach-v0", SMALL + ["checkpoint_interval=8"], offline_steps=16), run, dataset=ds)
    marker = tmp_path / "pwned"
    for name in ("checkpoint", "checkpoint.prev"):
        import shutil

        shutil.rmtree(run / name)
        _write_pickle_checkpoint(run / name, marker)
    with pytest.raises(CheckpointError, match="pickle"):
        train(resolve("bc", "toy-reach-v0", SMALL + ["checkpoint_interval=8"], offline_steps=16), run, dataset=ds)
    with pytest.raises(CheckpointError, match="pickle"):
        load_run(run)
    proc = subprocess.run(
        [sys.executable, "-m", "d5rl.cli", "eval", str(run), "--episodes", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: ") and "pickle" in proc.stderr.splitlines()[0]
    assert not marker.exists()


def test_pickle_bytes_in_the_new_format_do_not_run(tmp_path):
    """Even with a matching manifest, agent bytes go through msgpack, which builds data, not objects."""
    ds = toy_dataset(10)
    run = tmp_path / "run"
    train(resolve("bc", "toy-reach-v0", SMALL + ["checkpoint_interval=8"], offline_steps=8), run, dataset=ds)
    marker = tmp_path / "pwned"
    ckpt = load_checkpoint(run)
    save_checkpoint(run, Checkpoint(pickle.dumps(_Payload(marker)), ckpt.state))
    with pytest.raises(CheckpointError, match="does not fit this agent"):
        load_run(run)
    assert not marker.exists()


def test_damaged_latest_checkpoint_resumes_from_previous_and_matches(tmp_path, capsys):
    ds = toy_dataset(20)
    kw = SMALL + ["checkpoint_interval=16"]
    full = train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=64, seed=1), tmp_path / "a", dataset=ds)
    with pytest.raises(KeyboardInterrupt), interrupt_after_checkpoint(48):
        train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=64, seed=1), tmp_path / "b", dataset=ds)
    assert json.loads((tmp_path / "b" / "checkpoint" / "state.json").read_text())["step"] == 48
    _flip_byte(tmp_path / "b" / "checkpoint" / "agent.msgpack")
    capsys.readouterr()
    resumed = train(resolve("td3bc", "toy-reach-v0", kw, offline_steps=64, seed=1), tmp_path / "b", dataset=ds)
    err = capsys.readouterr().err
    assert "warning:" in err and "using the previous checkpoint" in err
    for a, b in zip(_leaves(full["agent"]), _leaves(resumed["agent"])):
        np.testing.assert_array_equal(a, b)


def test_a_checkpoint_of_another_observation_size_is_refused_in_one_line(tmp_path):
    """flax restores arrays of any shape: without a check the run failed deep in the first update."""
    run = tmp_path / "run"
    # a constant lr: BC's default decay horizon follows the run's length, and a longer run is another config
    overrides = SMALL + ["checkpoint_interval=8", "actor_decay_steps=0"]
    train(resolve("bc", "toy-reach-v0", overrides, offline_steps=8), run, dataset=toy_dataset(10))
    ds = toy_dataset(10)
    eps = [ds.episode(i) for i in range(ds.num_episodes)]
    for e in eps:
        e.arrays["observations"] = np.concatenate([e.arrays["observations"]] * 2, axis=1)
    with pytest.raises(CheckpointError, match=r"has shape \(4, 32\), this agent's \(8, 32\)"):
        train(
            resolve("bc", "toy-reach-v0", overrides, offline_steps=16),
            run,
            dataset=Dataset.from_episodes(eps, metadata=ds.metadata),
        )


def test_a_fresh_start_drops_the_metrics_of_a_killed_attempt_without_checkpoint(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text(json.dumps({"step": 4000, "stale/loss": 1.0}) + "\n")
    train(resolve("bc", "toy-reach-v0", SMALL, offline_steps=8), run, dataset=toy_dataset(10))
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert rows and all(r["step"] <= 8 and "stale/loss" not in r for r in rows)


# --- bounded reads and wrong types: one line, nothing read beyond what the manifest declares ------------------
def _one_checkpoint(tmp_path, buffer=None):
    save_checkpoint(tmp_path, Checkpoint(b"agent-1" * 10, {"step": 1}, buffer))
    return tmp_path / "checkpoint"


def _manifest_edit(d, edit):
    m = json.loads((d / "manifest.json").read_text())
    edit(m)
    (d / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize(
    "kind, match",
    [
        ("dev-zero", "is a character device, not a regular file"),
        ("fifo", "is a FIFO, not a regular file"),
        ("bigger", "more than the 70 it can be"),
    ],
)
def test_a_checkpoint_file_that_is_not_a_bounded_regular_file_is_refused_before_reading(tmp_path, kind, match):
    d = _one_checkpoint(tmp_path)
    target = d / "agent.msgpack"
    target.unlink()
    if kind == "dev-zero":
        target.symlink_to("/dev/zero")  # read whole, this is a MemoryError
    elif kind == "fifo":
        os.mkfifo(target)  # read, this blocks forever
    else:
        with open(target, "wb") as f:
            f.truncate(8 << 30)  # sparse: 8 GB declared by the file, 70 bytes by the manifest
    with pytest.raises(CheckpointError, match=match) as e:
        read_checkpoint(d)
    assert "\n" not in str(e.value)


def _npz_with(member: bytes, name="obs.npy", compress=False) -> bytes:
    import io
    import zipfile

    bio = io.BytesIO()
    with zipfile.ZipFile(bio, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as z:
        z.writestr(name, member)
    return bio.getvalue()


def _npy_header(shape, dtype="<f4") -> bytes:
    import io

    bio = io.BytesIO()
    np.lib.format.write_array_header_1_0(bio, {"descr": dtype, "fortran_order": False, "shape": shape})
    return bio.getvalue()


@pytest.mark.parametrize(
    "kind, match",
    [
        ("zip-bomb", "compressed, or larger than the archive"),
        ("huge-header", r"declares shape \(3000000000000,\)"),
        ("objects", "np.savez does not write|holds Python objects|unreadable"),
    ],
)
def test_a_crafted_buffer_npz_is_refused_before_allocating(tmp_path, kind, match):
    import hashlib

    if kind == "zip-bomb":  # 2 MB of zeros deflate to ~2 kB; 8 GB would deflate to a few MB
        blob = _npz_with(_npy_header((512 * 1024,)) + bytes(2 << 20), compress=True)
    elif kind == "huge-header":
        blob = _npz_with(_npy_header((3 * 10**12,)) + bytes(64))
    else:
        blob = _npz_with(_npy_header((1,), "|O") + b"\x80\x04N.")
    d = _one_checkpoint(tmp_path, {"meta": np.array([1, 0, 4])})
    (d / "buffer.npz").write_bytes(blob)
    _manifest_edit(
        d, lambda m: m["files"]["buffer.npz"].update(bytes=len(blob), sha256=hashlib.sha256(blob).hexdigest())
    )
    with pytest.raises(CheckpointError, match=match):
        read_checkpoint(d)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda m: m.update(files=["agent.msgpack"]), r"files is \['agent.msgpack'\], expected an object"),
        (lambda m: m["files"].update({"agent.msgpack": "70"}), "expected an object with the file's bytes and sha256"),
        (lambda m: m["files"]["agent.msgpack"].update(bytes="70"), "expected an object with the file's bytes"),
    ],
)
def test_wrong_types_in_a_checkpoint_manifest_are_one_line_errors(tmp_path, edit, match):
    d = _one_checkpoint(tmp_path)
    _manifest_edit(d, edit)
    with pytest.raises(CheckpointError, match=match):
        read_checkpoint(d)


def test_a_deeply_nested_checkpoint_manifest_is_a_one_line_error(tmp_path):
    d = _one_checkpoint(tmp_path)
    (d / "manifest.json").write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(CheckpointError, match="nests too deeply"):
        read_checkpoint(d)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("step", "abc", "step is 'abc', expected a non-negative integer"),
        ("rng", {"state": 1}, "rng is .*expected the state of numpy"),
        ("metric_sums", [1], "metric_sums is \\[1\\]"),
    ],
)
def test_wrong_types_in_a_run_state_are_one_line_errors(tmp_path, field, value, match):
    from d5rl.training.checkpoint import check_state
    from d5rl.training.parts import RunState

    good = RunState(np.random.default_rng(0), step=3).to_json()
    assert check_state(good, tmp_path) is good
    with pytest.raises(CheckpointError, match=match):
        check_state({**good, field: value}, tmp_path / "state.json")


@pytest.mark.parametrize(
    "text, match",
    [("{", "not valid JSON"), ('{"algo": 3}', "algo is 3, expected an algorithm"), ("[]", "expected a JSON object")],
)
def test_a_broken_run_config_is_a_one_line_error_under_eval(tmp_path, text, match):
    from d5rl.cli import main as cli_main

    (tmp_path / "config.json").write_text(text)
    with pytest.raises(Exception, match=match):
        load_run(tmp_path)
    assert cli_main(["eval", str(tmp_path)]) != 0


def test_eval_by_default_reproduces_the_runs_final_evaluation(tmp_path, capsys):
    """`d5rl eval RUN_DIR` replays the final evaluation (its episodes, seed and batch width) of the saved agent
    and says whether it scored what summary.json says; other options evaluate other episodes."""
    from d5rl.cli import main

    run = tmp_path / "run"
    overrides = SMALL + ["final_eval_episodes=4", "eval_envs=3"]
    train(resolve("bc", "toy-reach-v0", overrides, offline_steps=16, seed=2), run, dataset=toy_dataset(10))
    summary = json.loads((run / "summary.json").read_text())
    # each episode's return, length and score is kept, so the mean can be checked episode by episode
    assert len(summary["returns"]) == len(summary["lengths"]) == len(summary["scores"]) == 4
    assert np.mean(summary["scores"]) == pytest.approx(summary["score"], rel=1e-12)
    assert np.mean(summary["lengths"]) == summary["length"] and all(isinstance(n, int) for n in summary["lengths"])
    assert main(["eval", str(run), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["episodes"] == 4 and out["score"] == summary["score"] == out["final_evaluation_score"]
    assert out["episodes_not_the_same"] == [] and "scores" not in out
    assert main(["eval", str(run)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2] == f"the run's final evaluation (summary.json) scored {summary['score']:.3f}: the same"
    assert lines[-1].startswith(f"normalized score: {summary['score']:.3f} ± ")
    # an episode that scored otherwise is named
    (run / "summary.json").write_text(
        json.dumps({**summary, "scores": [*summary["scores"][:2], -1.0, summary["scores"][3]]})
    )
    assert main(["eval", str(run)]) == 0
    assert capsys.readouterr().out.splitlines()[-2].endswith(": not the same (episode 3 scored otherwise)")
    assert main(["eval", str(run), "--seed", "7", "--json"]) == 0
    other = json.loads(capsys.readouterr().out)
    assert "final_evaluation_score" not in other and other["score"] != summary["score"]
