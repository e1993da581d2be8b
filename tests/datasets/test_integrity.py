"""A damaged array never reaches a batch; generate repairs; writers and readers never break each other;
Ctrl-C and kill -9 leave only complete shards and no orphan workers."""

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from d5rl.cli import main as cli_main
from d5rl.datasets import format as fmt
from d5rl.datasets.generation import dataset_root, generate
from d5rl.datasets.loading import load_dataset
from d5rl.datasets.verify import verify_dataset
from d5rl.errors import DatasetCorruptError, DatasetVersionError
from d5rl.files import JSON_MAX_BYTES
from tests.datasets.test_generation import tree_digest
from tests.datasets.toy import register_toy

REPO = Path(__file__).resolve().parents[2]


def flip(path: Path, offset: int = -3) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def toy_cli(name, episodes, delay, *args, **popen):
    cmd = [sys.executable, "-m", "tests.datasets.toy", "cli", name, str(episodes), str(delay), "--", *args]
    return subprocess.Popen(
        cmd,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO), **popen.pop("env", {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return "\nState:\tZ" not in f.read()  # a zombie has exited
    except FileNotFoundError:
        return False


# --- integrity on load -----------------------------------------------------------------------------------
def test_flipped_byte_never_reaches_a_batch_and_is_repaired(capsys):
    spec = register_toy("flip", num_episodes=8, per_shard=4)
    clean = load_dataset(spec, progress=False).to_d4rl()
    target = dataset_root(spec.dataset) / "shards/shard-00001/observations.npy"
    flip(target)
    with pytest.raises(DatasetCorruptError, match="shard-00001/observations.npy: checksum mismatch") as e:
        load_dataset(spec, generate=False)
    assert "d5rl generate test-flip-v0" in e.value.hint
    capsys.readouterr()
    repaired = load_dataset(spec, progress=False).to_d4rl()  # generate=True: regenerates the shard
    assert "regenerating" in capsys.readouterr().err
    for k in clean:
        np.testing.assert_array_equal(clean[k], repaired[k])


def test_verified_shards_are_not_rehashed_until_they_change(monkeypatch):
    spec = register_toy("stamp", num_episodes=8, per_shard=4)
    generate(spec, progress=False)
    calls = []
    real = fmt.sha256_file
    monkeypatch.setattr(fmt, "sha256_file", lambda p: calls.append(Path(p).name) or real(p))
    fmt._STAMP_MEMO.clear()
    load_dataset(spec, generate=False)
    assert calls == []  # the writer's stamp vouches for the files it hashed when it committed
    path = dataset_root(spec.dataset) / "shards/shard-00000/actions.npy"
    os.utime(path, ns=(time.time_ns(), time.time_ns()))  # touched, not changed: re-hashed once, then trusted
    load_dataset(spec, generate=False)
    assert sorted(set(calls)) == sorted(p.name for p in path.parent.glob("*.npy"))
    calls.clear()
    load_dataset(spec, generate=False)
    assert calls == []


def test_unknown_manifest_format_is_refused():
    spec = register_toy("mfmt", num_episodes=4, per_shard=4)
    root = generate(spec, progress=False)
    m = json.loads((root / "manifest.json").read_text())
    m["format_version"] = 2
    (root / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(DatasetVersionError, match="format version 2"):
        load_dataset(spec, generate=False)
    with pytest.raises(DatasetVersionError, match="format version 2"):
        generate(spec, progress=False)


def test_generate_repairs_a_deleted_shard_as_verify_says(tmp_path, capsys):
    import shutil

    spec = register_toy("repair", num_episodes=12, per_shard=4)
    root = generate(spec, progress=False)
    before = tree_digest(root)
    shutil.rmtree(root / "shards/shard-00001")
    flip(root / "shards/shard-00002/rewards.npy")
    assert cli_main(["verify", spec.id]) == 1
    assert "d5rl generate test-repair-v0" in capsys.readouterr().err
    assert cli_main(["generate", spec.id, "--episodes", "8"]) == 0
    err = capsys.readouterr().err
    assert "repairing 2 damaged or missing part(s)" in err and "shard-00001" in err and "shard-00002" in err
    assert verify_dataset(spec).ok
    assert tree_digest(root) == before  # the same bytes as before the damage


# --- concurrency ------------------------------------------------------------------------------------------
def test_two_generators_of_one_dataset_both_succeed(tmp_path, monkeypatch):
    # the first generator runs ~6 s (32 episodes x 0.4 s on 2 workers), so the second one, started once
    # the first has written a shard, finds the lock held even on a loaded machine
    spec = register_toy("twogen", num_episodes=32, delay=0.4)
    root = dataset_root(spec.dataset)
    a = toy_cli("twogen", 32, 0.4, "generate", "test-twogen-v0", "--workers", "2")
    assert _wait_for(lambda: len(list((root / "shards").glob("shard-*"))) >= 1)
    b = toy_cli("twogen", 32, 0.4, "generate", "test-twogen-v0", "--workers", "2")
    out_a, out_b = a.communicate(timeout=120), b.communicate(timeout=120)
    assert a.returncode == 0, out_a[1][-2000:]
    assert b.returncode == 0, out_b[1][-2000:]
    assert "waiting for another d5rl process" in out_b[1]
    assert verify_dataset(spec).ok
    assert not list((root / "shards").glob(".shard-*"))
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "clean"))
    assert tree_digest(generate(spec, progress=False)) == tree_digest(root)


def test_reader_is_not_broken_by_a_generator_extending_the_dataset():
    spec = register_toy("readext", num_episodes=40, per_shard=4, delay=0.05)
    small = load_dataset(spec, episodes=6, progress=False)  # shard 1 holds episodes 4-5 only
    want = small.to_d4rl()
    proc = toy_cli("readext", 40, 0.05, "generate", "test-readext-v0", "--workers", "2")
    errors, loads = [], 0
    while proc.poll() is None:
        try:
            got = load_dataset(spec, episodes=6, generate=False).to_d4rl()
            for k in want:
                np.testing.assert_array_equal(want[k], got[k])
            loads += 1
        except Exception as e:  # noqa: BLE001
            errors.append(repr(e))
    assert proc.returncode == 0, proc.stderr.read()[-2000:]
    assert not errors, errors[:3]
    assert loads > 5
    assert load_dataset(spec, generate=False).num_episodes == 40


def test_two_writers_committing_one_shard(tmp_path):
    root = tmp_path / "ds"
    (root / "shards").mkdir(parents=True)
    errors = []

    def write(value, barrier):
        try:
            w = fmt.ShardWriter(root / "shards", 0)
            w.write("x", np.full(1000, value, np.int64))
            barrier.wait(timeout=10)
            w.commit({"episodes": [0, 1], "episode_lengths": [1000], "episode_meta": [{}]}, {"x": "transition"})
        except Exception as e:  # noqa: BLE001
            errors.append(e)

    for _ in range(20):
        barrier = threading.Barrier(2)
        threads = [threading.Thread(target=write, args=(v, barrier)) for v in (1, 2)]
        [t.start() for t in threads]
        [t.join() for t in threads]
    assert not errors, errors[:2]
    assert not fmt.verify_shard(root / "shards/shard-00000")
    assert sorted(p.name for p in (root / "shards").iterdir()) == ["shard-00000"]


def test_temporaries_of_a_live_writer_are_kept():
    spec = register_toy("tmpown", num_episodes=4, per_shard=4)
    root = generate(spec, progress=False)
    sleeper = subprocess.Popen(["sleep", "60"])
    try:
        live = root / "shards" / f".shard-00005.tmp-{os.uname().nodename}-{sleeper.pid}-abcd1234"
        live.mkdir()
        generate(spec, progress=False, force=False, num_episodes=4)
        fmt.clean_temporaries(root / "shards")
        assert live.exists()
    finally:
        sleeper.kill()
        sleeper.wait()
    fmt.clean_temporaries(root / "shards")
    assert not live.exists()


# --- stopping -----------------------------------------------------------------------------------------------
def _wait_for(pred, timeout=60.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return False


def test_ctrl_c_returns_fast_and_leaves_only_complete_shards(tmp_path):
    pids = tmp_path / "pids"
    pids.mkdir()
    proc = toy_cli(
        "ctrlc",
        60,
        0.3,
        "generate",
        "test-ctrlc-v0",
        "--workers",
        "2",
        env={"D5RL_TOY_PIDS": str(pids)},
        start_new_session=True,
    )
    spec = register_toy("ctrlc", num_episodes=60, delay=0.3)
    shards = dataset_root(spec.dataset) / "shards"
    assert _wait_for(lambda: len(list(shards.glob("shard-*"))) >= 1 and len(list(pids.iterdir())) >= 2)
    t0 = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole process group
    _, err = proc.communicate(timeout=30)
    elapsed = time.monotonic() - t0
    assert proc.returncode == 130, err[-2000:]
    assert elapsed < 3.0, elapsed
    assert "Traceback" not in err and "interrupted" in err
    assert not list(shards.glob(".shard-*"))  # no half-written temporaries
    for d in shards.glob("shard-*"):
        assert not fmt.verify_shard(d)  # every shard on disk is complete
    assert not [p for p in pids.iterdir() if int(p.name) != proc.pid and _alive(int(p.name))]


def test_killed_parent_leaves_no_workers(tmp_path):
    pids = tmp_path / "pids"
    pids.mkdir()
    proc = toy_cli("kill9", 24, 0.3, "generate", "test-kill9-v0", "--workers", "2", env={"D5RL_TOY_PIDS": str(pids)})
    assert _wait_for(lambda: len(list(pids.iterdir())) >= 2)
    workers = [int(p.name) for p in pids.iterdir()]
    proc.kill()
    proc.wait()
    assert _wait_for(lambda: not any(_alive(pid) for pid in workers), timeout=5.0), workers
    # and the next run resumes into a complete, intact dataset
    out = toy_cli("kill9", 24, 0.3, "generate", "test-kill9-v0", "--workers", "2")
    _, err = out.communicate(timeout=120)
    assert out.returncode == 0, err[-2000:]
    spec = register_toy("kill9", num_episodes=24, delay=0.3)
    assert verify_dataset(spec).ok


def test_digest_helper_ignores_bookkeeping(tmp_path):
    (tmp_path / ".write.lock").write_text("123")
    (tmp_path / "a.npy").write_bytes(b"x")
    assert tree_digest(tmp_path) == {"a.npy": hashlib.sha256(b"x").hexdigest()}


# --- manifest and shard-record damage: the command the hint names repairs it ---------------------------------
def _edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def _flip_digit(s: str) -> str:
    return ("1" if s[0] != "1" else "2") + s[1:]


def _repairs_as_the_hint_says(spec, root, before, capsys, match):
    with pytest.raises(DatasetCorruptError, match=match) as e:
        load_dataset(spec, generate=False)
    assert f"d5rl generate {spec.id}" in str(e.value.hint)
    capsys.readouterr()
    assert cli_main(["generate", spec.id]) == 0
    assert "repairing" in capsys.readouterr().err
    assert tree_digest(root) == before
    load_dataset(spec, generate=False)


@pytest.mark.parametrize(
    "damage", ["manifest-sha", "record-and-array", "garbage", "num_episodes-str", "not-object", "shards-missing"]
)
def test_damaged_manifest_or_record_is_repaired_by_the_command_the_hint_names(damage, capsys):
    spec = register_toy(f"mdmg-{damage.replace('_', '')}", num_episodes=12, per_shard=4)
    root = generate(spec, progress=False)
    before = tree_digest(root)
    manifest, shard = root / "manifest.json", root / "shards/shard-00001"
    if damage == "manifest-sha":  # the manifest is the damaged copy
        _edit_json(
            manifest,
            lambda m: m["shards"][1]["arrays"]["actions"].update(
                sha256=_flip_digit(m["shards"][1]["arrays"]["actions"]["sha256"])
            ),
        )
        match = "does not match the manifest"
    elif damage == "record-and-array":  # an array changed and its record made to agree: the manifest is right
        flip(shard / "actions.npy")
        _edit_json(
            shard / "shard.json", lambda r: r["arrays"]["actions"].update(sha256=fmt.sha256_file(shard / "actions.npy"))
        )
        match = "does not match the manifest"
    elif damage == "garbage":
        manifest.write_bytes(b"\x00garbage{")
        match = "not valid JSON"
    elif damage == "num_episodes-str":
        _edit_json(manifest, lambda m: m.update(num_episodes="12"))
        match = r"num_episodes is '12', expected a non-negative integer"
    elif damage == "not-object":
        manifest.write_text("[1, 2]")
        match = "expected a JSON object"
    else:
        _edit_json(manifest, lambda m: m.pop("shards"))
        match = "shards is None, expected a list of shards"
    _repairs_as_the_hint_says(spec, root, before, capsys, match)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("arrays", [1, 2], "arrays is \\[1, 2\\], expected an object of arrays"),
        ("episode_lengths", ["4"], "episode_lengths is \\['4'\\], expected 4 positive integers"),
        ("episodes", "0-4", "episodes is '0-4'"),
        ("file", "../../manifest.json", "file is '../../manifest.json', expected a file name inside the shard"),
    ],
)
def test_wrong_types_in_a_shard_record_are_one_line_errors_and_generate_repairs_them(field, value, match, capsys):
    spec = register_toy(f"rtyp-{field.replace('_', '')}", num_episodes=8, per_shard=4)
    root = generate(spec, progress=False)
    before = tree_digest(root)
    shard = root / "shards/shard-00000"
    if field == "file":
        _edit_json(shard / "shard.json", lambda r: r["arrays"]["actions"].update(file=value))
    else:
        _edit_json(shard / "shard.json", lambda r: r.update({field: value}))
    with pytest.raises(DatasetCorruptError, match=match):
        fmt.read_shard_record(shard)
    with pytest.raises(DatasetCorruptError):
        load_dataset(spec, generate=False)
    assert cli_main(["generate", spec.id]) == 0
    assert tree_digest(root) == before


def test_deeply_nested_json_is_a_one_line_error(tmp_path):
    spec = register_toy("deep", num_episodes=4, per_shard=4)
    root = generate(spec, progress=False)
    (root / "manifest.json").write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(DatasetCorruptError, match="nests too deeply"):
        load_dataset(spec, generate=False)
    assert cli_main(["generate", spec.id]) == 0
    load_dataset(spec, generate=False)


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "huge"])
def test_dataset_json_that_is_not_a_bounded_regular_file_is_refused_without_reading(kind):
    spec = register_toy(f"bound-{kind}", num_episodes=4, per_shard=4)
    root = generate(spec, progress=False)
    manifest = root / "manifest.json"
    manifest.unlink()
    if kind == "fifo":
        os.mkfifo(manifest)  # opening it for reading would block until a writer came
        match = "is a FIFO, not a regular file"
    elif kind == "dev-zero":
        manifest.symlink_to("/dev/zero")
        match = "is a character device, not a regular file"
    else:
        with open(manifest, "wb") as f:
            f.truncate(JSON_MAX_BYTES + 1)  # sparse: no disk used
        match = "more than the"
    with pytest.raises(DatasetCorruptError, match=match):
        load_dataset(spec, generate=False)
