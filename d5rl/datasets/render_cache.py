"""Camera frames rendered from a dataset's stored simulator states, cached next to it.

Datasets store states, not pixels: frames at any resolution and camera set are a
*derived cache*, rendered once and reused::

    <dataset root>/renders/<name>/shard-00000/{shard.json, observations.pixels.<cam>.zch}

Each cache shard mirrors a dataset shard (same episodes, step-aligned rows), is
written atomically with checksums (:class:`d5rl.datasets.format.ShardWriter`), and
records the checksum of the states it was rendered from, so a regenerated dataset
invalidates it.  Building is resumable (finished shards are kept), runs shards in a
process pool, shows a tqdm bar, and streams: one episode's frames at a time are
compressed into the shard's files, never the whole dataset.  Camera frames (uint8
rows of H x W x C) are stored losslessly as zstd-compressed chunks of consecutive
frames (:mod:`d5rl.datasets.chunks`, ~6x smaller than raw); other arrays (state
observations) as ``.npy``.  Caches written before compression (raw ``.npy`` frames)
are compressed in place the next time they are used, with a message, without
rendering again.  Re-rendering at another resolution only replays states; no
demonstrator or policy runs again.

A family plugs in with ``DatasetSpec.derived`` pointing at a small function that calls
:func:`ensure_render_cache` with its per-episode renderer ``"module:func"``
(``func(arrays, meta, **kwargs) -> {key: uint8 (T+1, H, W, 3)}``).  A builder that also takes
``check=False`` is first called with ``check=True`` (and no root) to check its arguments before any
data is generated (:func:`check_render_args` checks cameras and frame size).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from d5rl import parallel
from d5rl.datasets import format as fmt
from d5rl.datasets import lock
from d5rl.errors import DatasetArgumentError, is_int
from d5rl.progress import progress_bar
from d5rl.registry import resolve

RENDERS_DIR = "renders"
FRAME_SIZES = (8, 1024)  # the smallest and largest square frame a cache renders


def check_render_args(cameras, size: int, available: tuple[str, ...] | None = None) -> tuple[tuple[str, ...], int]:
    """A cache's camera names and frame size, checked before any work (a family's ``derived`` builder
    calls this first): ``cameras`` a non-empty list of distinct names from ``available``."""
    if available is not None and (
        isinstance(cameras, str)
        or not isinstance(cameras, (list, tuple))
        or not cameras
        or len(set(cameras)) != len(cameras)
        or not set(cameras) <= set(available)
    ):
        raise DatasetArgumentError(
            f"cameras must be a list of distinct names from {list(available)}, got {cameras!r}",
            f"pass e.g. cameras={list(available)}",
        )
    lo, hi = FRAME_SIZES
    if not is_int(size, lo=lo, hi=hi):
        raise DatasetArgumentError(
            f"size must be an integer number of pixels from {lo} to {hi}, got {size!r}",
            "pass e.g. size=64 (frames are size x size)",
        )
    return (None if available is None else tuple(cameras)), int(size)


def is_frames(shape, dtype) -> bool:
    """Whether an array is camera frames (uint8 rows of H x W x C), which are stored compressed."""
    return len(shape) == 4 and np.dtype(dtype) == np.uint8


def _shard_state(shard_dir: Path, source_sha: str, fn: str, kwargs: dict) -> str:
    """``"current"``: rendered from these states with these settings, intact (checksums, see
    format.check_shard) and compressed; ``"raw"``: the same but with uncompressed frames (an older
    d5rl's cache, to compress); ``"stale"``: anything else (to render)."""
    try:
        rec = fmt.read_shard_record(shard_dir)
    except Exception:  # noqa: BLE001 (a record that cannot be read, whatever the reason, means: render again)
        return "stale"
    if rec.get("source_states_sha256") != source_sha or rec.get("render") != {"fn": fn, "kwargs": kwargs}:
        return "stale"
    if fmt.check_shard(shard_dir, rec):
        return "stale"
    raw = any(is_frames(a["shape"], a["dtype"]) and "encoding" not in a for a in rec["arrays"].values())
    return "raw" if raw else "current"


def compress_shard(cache_shard: str, out_root: str, index: int) -> dict:
    """Rewrite one cache shard whose frames are raw ``.npy`` with compressed frames (atomic; the
    other arrays and the record's meaning are kept)."""
    src = Path(cache_shard)
    rec = fmt.read_shard_record(src)
    segments = [n + 1 for n in rec["episode_lengths"]]
    writer = fmt.ShardWriter(Path(out_root), index, lock_root=Path(out_root).parent.parent)
    try:
        for key, info in rec["arrays"].items():
            arr = fmt.open_array(src, info)
            if is_frames(info["shape"], info["dtype"]) and "encoding" not in info:
                w = writer.open_chunked(key, tuple(info["shape"][1:]), arr.dtype)
                start = 0
                for n in segments:
                    w.append(np.asarray(arr[start : start + n]))
                    start += n
            else:
                writer.write(key, np.asarray(arr))
        meta = {k: v for k, v in rec.items() if k not in ("format_version", "name", "arrays")}
        out = writer.commit(meta, {k: info["align"] for k, info in rec["arrays"].items()})
        parallel.report(len(segments))
        return out
    except BaseException:
        writer.abort()
        raise


def render_shard(dataset_shard: str, out_root: str, index: int, fn: str, kwargs: dict) -> dict:
    """Render every episode of one dataset shard into ``out_root/shard-XXXXX`` (atomic)."""
    src = Path(dataset_shard)
    rec = fmt.read_shard_record(src)
    states = fmt.open_array(src, rec["arrays"]["states"])  # memory-mapped
    render = resolve(fn)
    lengths = rec["episode_lengths"]
    total = sum(lengths) + len(lengths)
    writer = fmt.ShardWriter(Path(out_root), index, lock_root=Path(out_root).parent.parent)  # <root>/renders/<name>
    try:
        outs: dict = {}  # key -> memory-mapped .npy (filled by rows) or chunk writer (appended per episode)
        row = 0
        for ep_len, meta in zip(lengths, rec["episode_meta"]):
            ep_states = np.asarray(states[row : row + ep_len + 1])
            frames = render({"states": ep_states}, meta, **kwargs)
            for key, arr in frames.items():
                if len(arr) != ep_len + 1:
                    raise ValueError(f"{fn} returned {len(arr)} rows of {key!r} for {ep_len + 1} states")
                if key not in outs:
                    outs[key] = (
                        writer.open_chunked(key, arr.shape[1:], arr.dtype)
                        if is_frames(arr.shape, arr.dtype)
                        else writer.open(key, (total,) + arr.shape[1:], arr.dtype)
                    )
                if isinstance(outs[key], np.ndarray):
                    outs[key][row : row + ep_len + 1] = arr
                else:
                    outs[key].append(arr)
            row += ep_len + 1
            parallel.report(1)
        for m in outs.values():
            if isinstance(m, np.memmap):
                m.flush()
        del outs
        meta = {
            "episodes": rec["episodes"],
            "episode_lengths": lengths,
            "episode_meta": rec["episode_meta"],
            "source_states_sha256": rec["arrays"]["states"]["sha256"],
            "render": {"fn": fn, "kwargs": kwargs},
        }
        return writer.commit(meta, {k: "step" for k in writer.keys})
    except BaseException:
        writer.abort()
        raise


def observation_cache(
    spec,
    root: str | Path,
    manifest: dict,
    *,
    state: str,
    frames: str,
    frames_kwargs: dict[str, Any],
    frames_name: str,
    episodes: int | None,
    workers: parallel.Workers,
    progress: bool,
) -> list[Path]:
    """The one derived cache a task of a family with stored states reads: its state observations
    (``state``, for a ``-state`` task) or its camera frames (``frames(**frames_kwargs)`` under
    ``frames_name``), each a "module:function" of one episode's arrays and meta (:func:`render_shard`)."""
    if spec is not None and spec.observation == "state":
        fn, kwargs, name = state, {}, "state"
    else:
        fn, kwargs, name = frames, frames_kwargs, frames_name
    return [
        ensure_render_cache(
            root, manifest, fn, kwargs, name=name, episodes=episodes, workers=workers, progress=progress
        )
    ]


def ensure_render_cache(
    root: str | Path,
    manifest: dict,
    fn: str,
    kwargs: dict[str, Any],
    *,
    name: str,
    episodes: int | None = None,
    workers: parallel.Workers = None,
    progress: bool = True,
) -> Path:
    """Make sure ``root/renders/<name>`` holds up-to-date frames for the dataset's first ``episodes``
    episodes (whole shards); render what is missing.  Returns the cache directory."""
    root = Path(root)
    out = root / RENDERS_DIR / name
    kwargs = {k: (list(v) if isinstance(v, tuple) else v) for k, v in kwargs.items()}
    n = manifest["num_episodes"] if episodes is None else int(episodes)
    if not any(_jobs(root, out, manifest, n, fn, kwargs)[:2]):
        return out
    fmt.ensure_writable(out)
    with lock.writing(root, "rendering"):  # one writer at a time; check again under the lock
        fmt.clean_temporaries(out)
        jobs, migrate, todo_eps = _jobs(root, out, manifest, n, fn, kwargs)
        if migrate:
            print(
                f"note: {out} holds {len(migrate)} shard(s) of uncompressed frames written by an older d5rl; "
                "compressing them in place (lossless, no re-rendering)",
                file=sys.stderr,
                flush=True,
            )
        bar = None
        if progress and (jobs or migrate):
            bar = progress_bar(total=todo_eps, desc=f"rendering {name}", unit="ep")
        try:
            for func, todo in ((compress_shard, migrate), (render_shard, jobs)):
                if todo:
                    parallel.run_jobs(
                        func, todo, workers=workers, on_message=bar.update if bar is not None else None, shared_dir=out
                    )
        except OSError as e:
            full = fmt.disk_full_error(out, e)
            if full is None:
                raise
            raise full from None
        finally:
            if bar is not None:
                bar.close()
            fmt.clean_temporaries(out)
    return out


def _jobs(root: Path, out: Path, manifest: dict, n: int, fn: str, kwargs: dict) -> tuple[list, list, int]:
    """Render jobs for the shards of the first ``n`` episodes whose cache is missing, stale or damaged,
    compression jobs for those stored uncompressed, and how many episodes they hold."""
    jobs, migrate, todo_eps = [], [], 0
    for entry in manifest["shards"]:
        if entry["episodes"][0] >= n:
            break
        sha = entry["arrays"]["states"]["sha256"]
        state = _shard_state(out / entry["name"], sha, fn, kwargs)
        if state == "current":
            continue
        index = int(entry["name"].split("-")[1])
        if state == "raw":
            migrate.append((str(out / entry["name"]), str(out), index))
        else:
            jobs.append((str(root / "shards" / entry["name"]), str(out), index, fn, kwargs))
        todo_eps += entry["episodes"][1] - entry["episodes"][0]
    return jobs, migrate, todo_eps
