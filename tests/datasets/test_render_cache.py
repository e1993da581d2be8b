"""Generic render cache: frames from stored states, atomic per shard, resumable, invalidated by new states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from d5rl.datasets import format as fmt
from d5rl.datasets.render_cache import ensure_render_cache

CALLS: list[int] = []


def toy_render(arrays: dict, meta: dict, size: int = 4) -> dict:
    """A stand-in renderer: frame i of an episode is filled with the first state value."""
    CALLS.append(meta["id"])
    s = np.asarray(arrays["states"])
    frames = np.broadcast_to((s[:, :1, None, None] * 10).astype(np.uint8), (len(s), size, size, 3)).copy()
    return {"observations/pixels/toy": frames}


def _write_dataset(root: Path, lengths: list[list[int]], offset: float = 0.0) -> dict:
    shards, start = [], 0
    for i, group in enumerate(lengths):
        w = fmt.ShardWriter(root / "shards", i)
        states = np.concatenate(
            [np.arange(t + 1, dtype=np.float64)[:, None] + offset + np.zeros((1, 3)) for t in group]
        )
        w.write("states", states)
        ids = list(range(start, start + len(group)))
        rec = w.commit(
            {
                "episodes": [start, start + len(group)],
                "episode_lengths": group,
                "episode_meta": [{"id": k} for k in ids],
            },
            {"states": "step"},
        )
        shards.append({"name": rec["name"], "episodes": rec["episodes"], "arrays": rec["arrays"]})
        start += len(group)
    return {"num_episodes": start, "shards": shards}


FN = "tests.datasets.test_render_cache:toy_render"


def test_renders_every_shard_then_reuses_it(tmp_path):
    manifest = _write_dataset(tmp_path, [[3, 2], [4]])
    CALLS.clear()
    out = ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="toy-4x4", workers=1, progress=False)
    assert out == tmp_path / "renders" / "toy-4x4"
    assert sorted(CALLS) == [0, 1, 2]
    rec = fmt.read_shard_record(out / "shard-00000")
    assert rec["episode_lengths"] == [3, 2] and rec["arrays"]["observations/pixels/toy"]["align"] == "step"
    assert rec["arrays"]["observations/pixels/toy"]["encoding"] == "zstd-chunks-1"  # frames stored compressed
    frames = fmt.open_array(out / "shard-00000", rec["arrays"]["observations/pixels/toy"])
    assert frames.shape == (3 + 1 + 2 + 1, 4, 4, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames[:4, 0, 0, 0], [0, 10, 20, 30])  # rendered from the stored states
    assert not fmt.verify_shard(out / "shard-00000")  # checksums hold
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="toy-4x4", workers=1, progress=False)
    assert CALLS == []  # cached


def test_resumes_missing_shards_and_rerenders_stale_ones(tmp_path):
    manifest = _write_dataset(tmp_path, [[2], [2], [2]])
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="c", workers=1, progress=False)
    import shutil

    shutil.rmtree(tmp_path / "renders" / "c" / "shard-00001")
    (tmp_path / "renders" / "c" / ".shard-00002.tmp-999").mkdir()  # a killed writer's leftovers
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="c", workers=1, progress=False)
    assert CALLS == [1]
    assert not list((tmp_path / "renders" / "c").glob(".shard-*"))
    # new states (a regenerated dataset) invalidate the cache; other settings get their own frames
    manifest2 = _write_dataset(tmp_path, [[2], [2], [2]], offset=1.0)
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest2, FN, {"size": 4}, name="c", workers=1, progress=False)
    assert sorted(CALLS) == [0, 1, 2]
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest2, FN, {"size": 2}, name="c", workers=1, progress=False)
    assert sorted(CALLS) == [0, 1, 2]


def test_only_shards_needed_for_a_prefix(tmp_path):
    manifest = _write_dataset(tmp_path, [[2, 2], [2, 2], [2]])
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="p", episodes=3, workers=1, progress=False)
    assert sorted(CALLS) == [0, 1, 2, 3]  # whole shards covering episodes 0..2
    assert not (tmp_path / "renders" / "p" / "shard-00002").exists()


def test_failed_render_leaves_no_shard(tmp_path):
    manifest = _write_dataset(tmp_path, [[2]])
    with pytest.raises(AttributeError):
        ensure_render_cache(
            tmp_path, manifest, "tests.datasets.test_render_cache:no_such_fn", {}, name="x", workers=1, progress=False
        )
    assert not list((tmp_path / "renders" / "x").iterdir())


def test_process_pool(tmp_path):
    manifest = _write_dataset(tmp_path, [[2], [3]])
    out = ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="pool", workers=2, progress=False)
    for shard in ("shard-00000", "shard-00001"):
        assert not fmt.verify_shard(out / shard)


def test_an_uncompressed_cache_of_an_older_version_is_compressed_with_a_message(tmp_path, capsys):
    manifest = _write_dataset(tmp_path, [[3, 2], [4]])
    out = ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="old", workers=1, progress=False)
    expected = {}
    for i in range(2):  # rewrite each cache shard as an older d5rl did: raw .npy frames
        d = out / f"shard-0000{i}"
        rec = fmt.read_shard_record(d)
        frames = np.asarray(fmt.open_array(d, rec["arrays"]["observations/pixels/toy"]))
        expected[i] = frames
        w = fmt.ShardWriter(out, i, lock_root=tmp_path)
        w.write("observations/pixels/toy", frames)
        meta = {k: v for k, v in rec.items() if k not in ("format_version", "name", "arrays")}
        assert (
            "encoding" not in w.commit(meta, {"observations/pixels/toy": "step"})["arrays"]["observations/pixels/toy"]
        )
    capsys.readouterr()
    CALLS.clear()
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="old", workers=1, progress=False)
    assert CALLS == []  # nothing rendered again
    assert "uncompressed frames written by an older d5rl" in capsys.readouterr().err
    for i in range(2):
        d = out / f"shard-0000{i}"
        rec = fmt.read_shard_record(d)
        info = rec["arrays"]["observations/pixels/toy"]
        assert info["encoding"] == "zstd-chunks-1" and not fmt.verify_shard(d)
        np.testing.assert_array_equal(np.asarray(fmt.open_array(d, info)), expected[i])  # bit-exact
        assert not list(d.glob("*.npy"))
    capsys.readouterr()
    ensure_render_cache(tmp_path, manifest, FN, {"size": 4}, name="old", workers=1, progress=False)
    assert capsys.readouterr().err == ""  # compressed once
