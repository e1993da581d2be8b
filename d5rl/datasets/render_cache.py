"""Camera frames rendered from a dataset's stored simulator states, cached next to it.

Datasets store states, not pixels: frames at any resolution and camera set are a
*derived cache*, rendered once and reused::

    <dataset root>/renders/<name>/shard-00000/{shard.json, observations.pixels.<cam>.npy}

Each cache shard mirrors a dataset shard (same episodes, step-aligned rows), is
written atomically with checksums (:class:`d5rl.datasets.format.ShardWriter`), and
records the checksum of the states it was rendered from, so a regenerated dataset
invalidates it.  Building is resumable (finished shards are kept), runs shards in a
process pool, shows a tqdm bar, and streams: one episode's frames at a time go into
a memory-mapped file, never the whole dataset.  Re-rendering at another resolution
only replays states; no demonstrator or policy runs again.

A family plugs in with ``DatasetSpec.derived`` pointing at a small function that calls
:func:`ensure_render_cache` with its per-episode renderer ``"module:func"``
(``func(arrays, meta, **kwargs) -> {key: uint8 (T+1, H, W, 3)}``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from d5rl import parallel
from d5rl.datasets import format as fmt
from d5rl.datasets import lock
from d5rl.registry import resolve

RENDERS_DIR = "renders"


def _shard_is_current(shard_dir: Path, source_sha: str, fn: str, kwargs: dict) -> bool:
    """Rendered from these states with these settings, and intact (checksums, see format.check_shard)."""
    try:
        rec = fmt.read_shard_record(shard_dir)
    except Exception:
        return False
    if rec.get("source_states_sha256") != source_sha or rec.get("render") != {"fn": fn, "kwargs": kwargs}:
        return False
    return not fmt.check_shard(shard_dir, rec)


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
        outs: dict[str, np.memmap] = {}
        row = 0
        for ep_len, meta in zip(lengths, rec["episode_meta"]):
            ep_states = np.asarray(states[row : row + ep_len + 1])
            frames = render({"states": ep_states}, meta, **kwargs)
            for key, arr in frames.items():
                if len(arr) != ep_len + 1:
                    raise ValueError(f"{fn} returned {len(arr)} rows of {key!r} for {ep_len + 1} states")
                if key not in outs:
                    outs[key] = writer.open(key, (total,) + arr.shape[1:], arr.dtype)
                outs[key][row : row + ep_len + 1] = arr
            row += ep_len + 1
            parallel.report(1)
        for m in outs.values():
            m.flush()
        del outs
        meta = {
            "episodes": rec["episodes"],
            "episode_lengths": lengths,
            "episode_meta": rec["episode_meta"],
            "source_states_sha256": rec["arrays"]["states"]["sha256"],
            "render": {"fn": fn, "kwargs": kwargs},
        }
        keys = [fmt.filename_to_key(p.name) for p in writer.tmp.glob("*.npy")]
        return writer.commit(meta, {k: "step" for k in keys})
    except BaseException:
        writer.abort()
        raise


def ensure_render_cache(root: str | Path, manifest: dict, fn: str, kwargs: dict[str, Any], *, name: str,
                        episodes: int | None = None, workers: parallel.Workers = None,
                        progress: bool = True) -> Path:
    """Make sure ``root/renders/<name>`` holds up-to-date frames for the dataset's first ``episodes``
    episodes (whole shards); render what is missing.  Returns the cache directory."""
    root = Path(root)
    out = root / RENDERS_DIR / name
    kwargs = {k: (list(v) if isinstance(v, tuple) else v) for k, v in kwargs.items()}
    n = manifest["num_episodes"] if episodes is None else int(episodes)
    if not _jobs(root, out, manifest, n, fn, kwargs)[0]:
        return out
    fmt.ensure_writable(out)
    with lock.writing(root, "rendering"):  # one writer at a time; check again under the lock
        fmt.clean_temporaries(out)
        jobs, todo_eps = _jobs(root, out, manifest, n, fn, kwargs)
        if not jobs:
            return out
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=todo_eps, desc=f"rendering {name}", unit="ep")
        try:
            parallel.run_jobs(render_shard, jobs, workers=workers, on_message=bar.update if bar is not None else None,
                              shared_dir=out)
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


def _jobs(root: Path, out: Path, manifest: dict, n: int, fn: str, kwargs: dict) -> tuple[list[tuple], int]:
    """Render jobs for the shards of the first ``n`` episodes whose cache is missing, stale or damaged."""
    jobs, todo_eps = [], 0
    for entry in manifest["shards"]:
        if entry["episodes"][0] >= n:
            break
        sha = entry["arrays"]["states"]["sha256"]
        if _shard_is_current(out / entry["name"], sha, fn, kwargs):
            continue
        index = int(entry["name"].split("-")[1])
        jobs.append((str(root / "shards" / entry["name"]), str(out), index, fn, kwargs))
        todo_eps += entry["episodes"][1] - entry["episodes"][0]
    return jobs, todo_eps
