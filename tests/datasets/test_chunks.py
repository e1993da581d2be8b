"""Compressed chunked frames: bit-exact round trips, damage detected, sampling identical to raw frames."""

from __future__ import annotations

import numpy as np
import pytest

from d5rl.datasets import chunks
from d5rl.datasets import format as fmt
from d5rl.datasets.dataset import ChunkedArray, Dataset
from d5rl.errors import DatasetCorruptError


def _frames(n: int, seed: int = 0, size: int = 12) -> np.ndarray:
    """Frames like a camera's: a smooth moving pattern plus noise (compressible, not constant)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None, None, None]
    y, x = np.mgrid[0:size, 0:size][..., None]
    base = (x * 9 + y * 5 + t * 3 + np.arange(3) * 40) % 256
    return (base + rng.integers(0, 4, (n, size, size, 3))).astype(np.uint8)


def test_round_trip_is_bit_exact_for_every_kind_of_index(tmp_path):
    frames = _frames(61)
    segments = [17, 1, 40, 3]  # chunks restart at each segment (episode)
    shape = chunks.compress_array(tmp_path / "a.zch", frames, segments, chunk_rows=8)
    assert shape == frames.shape
    arr = chunks.CompressedArray(tmp_path / "a.zch")
    assert arr.shape == frames.shape and arr.dtype == np.uint8 and len(arr) == 61
    # chunk boundaries: every segment start, then every 8 rows within it
    assert list(arr.row_starts) == [0, 8, 16, 17, 18, 26, 34, 42, 50, 58, 61]
    np.testing.assert_array_equal(np.asarray(arr), frames)
    np.testing.assert_array_equal(arr[5], frames[5])
    np.testing.assert_array_equal(arr[-1], frames[-1])
    np.testing.assert_array_equal(arr[10:45], frames[10:45])
    np.testing.assert_array_equal(arr[3:50:7], frames[3:50:7])
    np.testing.assert_array_equal(arr[:30, 2, 1:5, 0], frames[:30, 2, 1:5, 0])
    np.testing.assert_array_equal(arr[7, :, 3], frames[7, :, 3])
    idx = np.random.default_rng(1).integers(0, 61, (5, 7))
    np.testing.assert_array_equal(arr[idx], frames[idx])
    head = arr.head(20)
    assert len(head) == 20
    np.testing.assert_array_equal(np.asarray(head), frames[:20])
    with pytest.raises(IndexError):
        head[np.array([20])]
    # consecutive similar frames compress together (the point of chunks): 8 copies of a noisy frame
    same = np.repeat(_frames(1, seed=9), 8, axis=0)
    chunks.compress_array(tmp_path / "b.zch", same, chunk_rows=8)
    assert (tmp_path / "b.zch").stat().st_size < same.nbytes / 4


def test_shard_writer_stores_compressed_frames_and_reads_them_back(tmp_path):
    frames = _frames(30, seed=2)
    w = fmt.ShardWriter(tmp_path, 0)
    cw = w.open_chunked("observations/pixels/cam", frames.shape[1:], np.uint8)
    cw.append(frames[:12])
    cw.append(frames[12:])
    w.write("states", np.zeros((30, 2)))
    rec = w.commit(
        {"episodes": [0, 1], "episode_lengths": [29], "episode_meta": [{}]},
        {"observations/pixels/cam": "step", "states": "step"},
    )
    info = rec["arrays"]["observations/pixels/cam"]
    assert info["encoding"] == chunks.ENCODING and info["file"].endswith(".zch") and info["shape"] == [30, 12, 12, 3]
    d = tmp_path / "shard-00000"
    assert not fmt.verify_shard(d)
    arr = fmt.open_array(d, info)
    np.testing.assert_array_equal(np.asarray(arr), frames)
    np.testing.assert_array_equal(np.asarray(fmt.first_rows(arr, 12)), frames[:12])


def test_a_damaged_chunk_is_detected(tmp_path):
    frames = _frames(40, seed=3)
    w = fmt.ShardWriter(tmp_path, 0)
    w.open_chunked("observations/pixels/cam", frames.shape[1:], np.uint8).append(frames)
    rec = w.commit({}, {"observations/pixels/cam": "step"})
    d = tmp_path / "shard-00000"
    path = d / rec["arrays"]["observations/pixels/cam"]["file"]
    arr = chunks.CompressedArray(path)
    raw = bytearray(path.read_bytes())
    raw[int(arr.offsets[1]) + 20] ^= 0xFF  # a flipped byte inside chunk 1
    path.write_bytes(bytes(raw))
    problems = fmt.check_shard(d, rec)  # what loading does first: the file's checksum
    assert problems and "checksum mismatch" in problems[0]
    damaged = chunks.CompressedArray(path)  # and zstd's own checksum, should the file be read anyway
    np.testing.assert_array_equal(damaged[0], frames[0])  # chunk 0 is intact
    with pytest.raises(DatasetCorruptError, match="chunk 1"):
        damaged[int(arr.row_starts[1])]
    path.write_bytes(bytes(raw[:-5]))  # a truncated file
    with pytest.raises(DatasetCorruptError, match="unreadable"):
        fmt.open_array(d, rec["arrays"]["observations/pixels/cam"])


def test_sampling_compressed_frames_equals_sampling_raw_frames(tmp_path):
    lengths = [9, 14, 6]
    frames = _frames(sum(lengths) + len(lengths), seed=4)
    segments = [n + 1 for n in lengths]
    chunks.compress_array(tmp_path / "f.zch", frames, segments, chunk_rows=4)
    n = sum(lengths)
    rng = np.random.default_rng(0)
    common = {
        "actions": rng.normal(size=(n, 2)).astype(np.float32),
        "rewards": np.zeros(n, np.float32),
        "terminals": np.zeros(n, bool),
        "timeouts": np.zeros(n, bool),
    }
    aligns = {
        "actions": "transition",
        "rewards": "transition",
        "terminals": "transition",
        "timeouts": "transition",
        "observations/pixels/cam": "step",
    }
    raw = Dataset({**common, "observations/pixels/cam": frames}, aligns, np.array(lengths))
    comp = chunks.CompressedArray(tmp_path / "f.zch")
    split = ChunkedArray([comp.head(10), frames[10:]])  # a compressed shard followed by a raw one
    for arr in (comp, split):
        ds = Dataset({**common, "observations/pixels/cam": arr}, aligns, np.array(lengths))
        for stack in (1, 3):
            a = raw.sample(50, np.random.default_rng(7), frame_stack=stack)
            b = ds.sample(50, np.random.default_rng(7), frame_stack=stack)
            for key in ("observations", "next_observations"):
                np.testing.assert_array_equal(a[key]["pixels/cam"], b[key]["pixels/cam"])
    # the stacked frames themselves: an episode's first step repeats its first frame
    batch = raw.sample(3, rng, frame_stack=3, indices=np.array([0, 9, 10]))
    obs, nxt = batch["observations"]["pixels/cam"], batch["next_observations"]["pixels/cam"]
    np.testing.assert_array_equal(obs[0], np.concatenate([frames[0]] * 3, axis=-1))
    np.testing.assert_array_equal(nxt[0], np.concatenate([frames[0], frames[0], frames[1]], axis=-1))
    np.testing.assert_array_equal(obs[1], np.concatenate([frames[10]] * 3, axis=-1))  # episode 1 starts at row 10
    np.testing.assert_array_equal(nxt[2], np.concatenate([frames[10], frames[11], frames[12]], axis=-1))
