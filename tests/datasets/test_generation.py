import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d5rl.datasets import format as fmt
from d5rl.datasets.generation import dataset_root, generate
from d5rl.datasets.loading import load_dataset
from d5rl.datasets.verify import verify_dataset
from d5rl.errors import DatasetCorruptError, DatasetNotFoundError, DatasetVersionError
from d5rl.files import dump_json
from tests.datasets.toy import register_toy

REPO = Path(__file__).resolve().parents[2]


def tree_digest(root: Path) -> dict[str, str]:
    """sha256 of every data file; dotfiles are bookkeeping (locks, verification stamps), not data."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and not p.name.startswith(".")
    }


def test_same_seed_same_bytes_any_worker_count(tmp_path, monkeypatch):
    spec = register_toy("det", num_episodes=10, per_shard=3)
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "a"))
    a = tree_digest(generate(spec, workers=1, progress=False))
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "b"))
    b = tree_digest(generate(spec, workers=2, progress=False))
    assert a == b
    assert "manifest.json" in a and len([k for k in a if k.endswith("shard.json")]) == 4
    c = tree_digest(generate(spec, seed=1, workers=1, progress=False))
    assert c["manifest.json"] != a["manifest.json"]


def test_ray_backend_writes_the_same_bytes(tmp_path, monkeypatch):
    ray = pytest.importorskip("ray")
    from d5rl.parallel import Ray

    spec = register_toy("ray", num_episodes=7, per_shard=2)
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "a"))
    a = tree_digest(generate(spec, workers=1, progress=False))
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "b"))
    portable = register_toy("ray-portable", num_episodes=2, per_shard=2, numerics="portable")
    try:
        b = tree_digest(generate(spec, workers=Ray("local"), progress=False))
        # a portable dataset's Ray workers start with the pinned environment (they refuse the work otherwise)
        root = generate(portable, workers=Ray("local"), progress=False)
    finally:
        ray.shutdown()  # later tests in this worker start their own instance
    assert a == b  # nothing left behind either (the shared-directory check file is removed)
    from d5rl import numerics

    assert fmt.read_manifest(root / fmt.MANIFEST)["numerics"] == ("portable" if numerics.supported() else "native")


def test_run_jobs_reports_progress_and_keeps_job_order():
    from d5rl import parallel

    got, finished = [], []
    out = parallel.run_jobs(
        _square_and_report,
        [(i,) for i in range(5)],
        workers=2,
        on_message=got.append,
        on_result=lambda i, r: finished.append(i),
    )
    assert out == [0, 1, 4, 9, 16]
    assert sorted(got) == [0, 1, 2, 3, 4] and sorted(finished) == [0, 1, 2, 3, 4]


def _square_and_report(i):
    from d5rl import parallel

    parallel.report(i)
    return i * i


def test_round_trip_matches_generator():
    spec = register_toy("rt", num_episodes=9, per_shard=4)
    ds = load_dataset(spec, progress=False)
    from d5rl.datasets.generation import episode_rng, make_generator

    gen = make_generator(spec)
    assert ds.num_episodes == 9
    for i in range(9):
        want = gen.episode(i, episode_rng(0, i))
        got = ds.episode(i)
        assert got.meta == want.meta
        assert sorted(got.arrays) == sorted(want.arrays)
        for k in want.arrays:
            np.testing.assert_array_equal(got.arrays[k], want.arrays[k])
            assert got.arrays[k].dtype == want.arrays[k].dtype


def test_memory_mapped_view_equals_in_memory():
    spec = register_toy("mm", num_episodes=11, per_shard=3)
    a = load_dataset(spec, in_memory=False, progress=False)
    b = load_dataset(spec, in_memory=True, progress=False)
    assert not isinstance(a.arrays["observations"], np.ndarray) or isinstance(a.arrays["observations"], np.memmap)
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(a), 50)
    ba, bb = a.sample(50, rng, indices=idx), b.sample(50, rng, indices=idx)
    for k in ba:
        np.testing.assert_array_equal(ba[k], bb[k])


def test_memory_limit_decides_what_is_read_into_ram():
    spec = register_toy("lim", num_episodes=5, per_shard=5)
    on_disk = load_dataset(spec, memory_limit_bytes=0, progress=False)
    in_ram = load_dataset(spec, memory_limit_bytes=1 << 40, progress=False)
    assert isinstance(on_disk.arrays["observations"], np.memmap)
    assert type(in_ram.arrays["observations"]) is np.ndarray
    np.testing.assert_array_equal(on_disk.arrays["observations"], in_ram.arrays["observations"])
    with pytest.raises(ValueError, match="memory_limit_bytes"):
        load_dataset(spec, memory_limit_bytes=-1, progress=False)


def test_prefix_and_extension_share_bytes(tmp_path, monkeypatch):
    spec = register_toy("ext", num_episodes=10, per_shard=4)
    small = load_dataset(spec, episodes=5, progress=False)
    assert small.num_episodes == 5
    full = load_dataset(spec, progress=False)  # extends 5 -> 10
    assert full.num_episodes == 10
    for i in range(5):
        np.testing.assert_array_equal(small.episode(i).arrays["actions"], full.episode(i).arrays["actions"])
    extended = tree_digest(dataset_root(spec.dataset))
    monkeypatch.setenv("D5RL_HOME", str(tmp_path / "fresh"))
    assert tree_digest(generate(spec, progress=False)) == extended
    assert load_dataset(spec, episodes=3, progress=False).num_episodes == 3


def test_missing_dataset_without_generate_says_what_to_do():
    spec = register_toy("missing")
    with pytest.raises(DatasetNotFoundError, match="d5rl generate test-missing-v0"):
        load_dataset(spec, generate=False)


def test_resume_after_kill_gives_identical_bytes(tmp_path, monkeypatch):
    env = {**os.environ, "D5RL_HOME": str(tmp_path / "killed"), "PYTHONPATH": str(REPO)}
    args = [sys.executable, "-m", "tests.datasets.toy", "resume", "24", "0.15", "1"]
    proc = subprocess.Popen(args, env=env, cwd=REPO)
    shards = tmp_path / "killed/datasets/test-resume/v1-seed0/shards"
    deadline = time.time() + 60
    while time.time() < deadline and len(list(shards.glob("shard-*"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = sorted(p.name for p in shards.glob("shard-*"))
    assert 2 <= len(done_before) < 6, done_before
    assert not (shards.parent / "manifest.json").exists()
    mtimes = {p.name: (p / "shard.json").stat().st_mtime_ns for p in shards.glob("shard-*")}

    subprocess.run(args, env=env, cwd=REPO, check=True, timeout=120)
    for name, mt in mtimes.items():  # finished shards were kept, not redone
        assert (shards / name / "shard.json").stat().st_mtime_ns == mt
    assert not list(shards.glob(".shard-*"))  # temporaries of the killed writer are gone

    env_clean = {**env, "D5RL_HOME": str(tmp_path / "clean")}
    subprocess.run(args, env=env_clean, cwd=REPO, check=True, timeout=120)
    assert tree_digest(shards.parent) == tree_digest(tmp_path / "clean/datasets/test-resume/v1-seed0")


def test_verify_detects_corruption_and_loader_refuses_truncation():
    spec = register_toy("corrupt", num_episodes=8, per_shard=4)
    root = generate(spec, progress=False)
    assert verify_dataset(spec).ok
    target = root / "shards/shard-00001/actions.npy"
    data = bytearray(target.read_bytes())
    data[-3] ^= 0xFF
    target.write_bytes(bytes(data))
    report = verify_dataset(spec)
    assert not report.ok
    assert any("shard-00001/actions.npy" in p and "checksum" in p for p in report.problems)

    (root / "shards/shard-00000/rewards.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(DatasetCorruptError, match="shard-00000"):
        load_dataset(spec, generate=False)


def test_changed_generator_version_is_refused(monkeypatch):
    spec = register_toy("stale", num_episodes=4, per_shard=4)
    generate(spec, progress=False)
    from tests.datasets import toy

    monkeypatch.setattr(toy.ToyGenerator, "version", "2")
    with pytest.raises(DatasetVersionError, match="--force"):
        load_dataset(spec, generate=False)
    with pytest.raises(DatasetVersionError):
        generate(spec, progress=False)
    generate(spec, force=True, progress=False)
    assert load_dataset(spec).metadata["generator_version"] == "2"


def test_bad_format_version_is_refused():
    spec = register_toy("fmtver", num_episodes=4, per_shard=4)
    root = generate(spec, progress=False)
    rec = fmt.load_json(root / "shards/shard-00000/shard.json", "x")
    rec["format_version"] = 999
    dump_json(rec, root / "shards/shard-00000/shard.json")
    with pytest.raises(DatasetVersionError, match="format version 999"):
        load_dataset(spec, generate=False)


def test_relabel_replaces_rewards():
    base = register_toy("relabel-base", num_episodes=4)
    twin = register_toy("relabel-twin", num_episodes=4, relabel="tests.datasets.toy:relabel_double")
    a, b = load_dataset(base, progress=False), load_dataset(twin, progress=False)
    np.testing.assert_array_equal(b.rewards, 2 * a.rewards)


def test_tuple_generator_kwargs_survive_the_json_round_trip():
    spec = register_toy("tuplekw", num_episodes=4, per_shard=4, extra=("a", "b"))
    generate(spec, progress=False)
    assert load_dataset(spec, generate=False).num_episodes == 4  # tuple vs list must not look stale


def _run_script(tmp_path, text: str, timeout: float = 90):
    script = tmp_path / "script.py"
    script.write_text(text)
    env = {**os.environ, "D5RL_HOME": str(tmp_path / "home"), "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, str(script)], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=timeout
    )


def test_a_script_without_the_main_guard_generates_several_shards_in_a_pool(tmp_path):
    # spawn workers re-run the main script unless told otherwise: here that would call load_dataset
    # again in each worker, which waits for the parent's write lock while the parent waits for it.
    proc = _run_script(
        tmp_path,
        "import d5rl\n"
        "ds = d5rl.load_dataset('toy-reach-v0', episodes=120, workers=2, progress=False)\n"
        "print('episodes', ds.num_episodes)\n",
    )
    assert proc.returncode == 0, proc.stderr
    assert "episodes 120" in proc.stdout
    assert len(list((tmp_path / "home/datasets/toy-reach").glob("v*/shards/shard-*"))) == 3


def test_a_script_without_the_guard_whose_jobs_need_it_stops_with_the_guard_named(tmp_path):
    # A generator defined in the script itself: the workers must re-run the script to find it.
    proc = _run_script(
        tmp_path,
        "import d5rl\n"
        "from tests.datasets.toy import ToyGenerator, register_toy\n"
        "class ScriptGenerator(ToyGenerator):\n    pass\n"
        "import dataclasses\n"
        "spec = register_toy('noguard', num_episodes=12, per_shard=4)\n"
        "spec = dataclasses.replace(spec, dataset=dataclasses.replace(\n"
        "    spec.dataset, generator='__main__:ScriptGenerator'))\n"
        "d5rl.load_dataset(spec, workers=2, progress=False)\n",
    )
    assert proc.returncode != 0
    assert 'if __name__ == "__main__":' in proc.stderr
    assert "Traceback" not in proc.stderr.split("d5rl: error:")[0]
