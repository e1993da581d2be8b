"""Loading a task's dataset from disk: every shard checked, missing or damaged data regenerated
(or refused), derived caches built, arrays read into RAM or memory-mapped into a
:class:`~d5rl.datasets.dataset.Dataset`."""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from d5rl.datasets import format as fmt
from d5rl.datasets import generation, lock
from d5rl.datasets.dataset import ChunkedArray, Dataset
from d5rl.errors import D5RLError, DatasetArgumentError, DatasetCorruptError, DatasetNotFoundError
from d5rl.registry import TaskSpec, get_spec, resolve

# Arrays at most this large are read into RAM by default (fast sampling);
# larger ones (camera frames) stay memory-mapped.
IN_MEMORY_LIMIT_BYTES = 1 << 30


# --- loading from disk ----------------------------------------------------------------------------
def _shard_chunks(shard_dirs: list[Path], records: list[dict], n_eps_last: int | None):
    """Per-key lists of memory-mapped chunks, the last shard cut to ``n_eps_last`` episodes."""
    chunks: dict[str, list[np.ndarray]] = {}
    aligns: dict[str, str] = {}
    for j, (d, rec) in enumerate(zip(shard_dirs, records)):
        lengths = rec["episode_lengths"]
        keep = len(lengths) if (j < len(records) - 1 or n_eps_last is None) else n_eps_last
        n_t = int(sum(lengths[:keep]))
        for key, info in rec["arrays"].items():
            arr = fmt.open_array(d, info)
            rows = n_t + (keep if info["align"] == "step" else 0)
            chunks.setdefault(key, []).append(fmt.first_rows(arr, rows))
            aligns[key] = info["align"]
    return chunks, aligns


def _extends(rec: dict, entry: dict, manifest: dict) -> bool:
    """Whether ``rec`` is the manifest's last, partial shard already rewritten by a generator that is
    extending the dataset: same generator and seed, same first episode, more episodes.  Generation is
    deterministic, so the episodes the manifest promises are the same bytes in it."""
    same = all(
        rec.get(k) == manifest.get(k)
        for k in ("dataset", "dataset_version", "generator", "generator_version", "generator_kwargs", "seed")
    )
    return same and rec["episodes"][0] == entry["episodes"][0] and rec["episodes"][1] > entry["episodes"][1]


class _NotReady(Exception):
    """Internal: the data on disk cannot be served as asked (missing, too short, or damaged)."""

    def __init__(self, error: D5RLError, damaged: bool = False):
        super().__init__(error.message)
        self.error, self.damaged = error, damaged


def load_dataset(
    task: str | TaskSpec,
    *,
    seed: int | None = None,
    episodes: int | None = None,
    generate: bool = True,
    in_memory: bool | str = "auto",
    memory_limit_bytes: int | None = None,
    obs_keys: list[str] | None = None,
    workers: int | None = None,
    progress: bool = True,
    **derived_kwargs,
) -> Dataset:
    """Load a task's dataset (generating it first if missing and ``generate``).

    ``episodes`` takes the first N episodes (a smaller dataset is a prefix of the
    full one).  ``in_memory``: True reads everything into RAM, False keeps every
    array memory-mapped, "auto" reads arrays up to ``memory_limit_bytes`` (default 1 GiB;
    compressed camera frames read into RAM are decoded once instead of at every batch, see
    the trainer's ``dataset_in_memory_gb``).  Extra keyword arguments
    go to the dataset's derived-cache builder (e.g. ``cameras=``, ``size=`` for
    rendered frames).

    Every shard used is checked against its checksums before any array is handed out
    (re-hashed only if its files changed since the last check; see
    :func:`d5rl.datasets.format.check_shard`).  A damaged or missing shard is regenerated
    when ``generate`` is true (with a one-line warning), else raises
    :class:`~d5rl.errors.DatasetCorruptError`.
    """
    spec = get_spec(task)
    dspec = generation.dataset_spec(spec)
    if dspec.imported:
        dspec = _imported_spec(spec, dspec, seed)
    seed = generation.check_seed(dspec.default_seed if seed is None else seed)
    wanted = generation.check_episodes(episodes, dspec)
    _check_derived_kwargs(spec, dspec, derived_kwargs)
    root = generation.dataset_root(dspec, seed)
    limit = IN_MEMORY_LIMIT_BYTES if memory_limit_bytes is None else int(memory_limit_bytes)
    if limit < 0:
        raise ValueError(f"memory_limit_bytes must be >= 0, got {memory_limit_bytes}")
    if episodes is None and not generate and (root / fmt.MANIFEST).exists():
        with contextlib.suppress(_NotReady):  # a damaged manifest is reported by _open below
            wanted = min(wanted, _manifest(root / fmt.MANIFEST, spec, dspec)["num_episodes"]) or wanted  # what is there
    for attempt in range(3):
        try:
            return _open(
                spec,
                dspec,
                seed=seed,
                root=root,
                wanted=wanted,
                partial=episodes is not None,
                in_memory=in_memory,
                limit=limit,
                obs_keys=obs_keys,
                workers=workers,
                progress=progress,
                derived_kwargs=derived_kwargs,
            )
        except _NotReady as e:
            if not generate or attempt == 2 or dspec.imported:
                raise e.error from None
            if e.damaged:
                print(f"warning: {e.error.message}; regenerating it", file=sys.stderr, flush=True)
            generation.generate(spec, seed=seed, num_episodes=wanted, workers=workers, progress=progress)
    raise AssertionError("unreachable")


def _imported_spec(spec: TaskSpec, dspec, seed):
    """An imported dataset's spec with its full size as imported (d5rl cannot make more); one-line
    errors when it was not imported, or for a seed (imported data has none)."""
    import dataclasses

    if seed is not None and seed != dspec.default_seed:
        raise DatasetArgumentError(
            f"{spec.id}'s dataset is imported and has no seed; {seed!r} was given", "omit seed= (--seed)"
        )
    path = generation.dataset_root(dspec) / fmt.MANIFEST
    if not path.exists():
        raise generation.not_imported_error(spec, dspec)
    return dataclasses.replace(dspec, num_episodes=fmt.read_manifest(path)["num_episodes"])


def _check_derived_kwargs(spec: TaskSpec, dspec, kwargs: dict) -> None:
    """Refuse keyword arguments that the dataset's derived-cache builder does not take, or values it
    cannot use, before any generation (else a typo would surface only after generating the dataset)."""
    import difflib
    import inspect

    if not kwargs:
        return
    own = [name for name, p in inspect.signature(load_dataset).parameters.items() if p.kind is p.KEYWORD_ONLY]
    builder = None if dspec.derived is None else resolve(dspec.derived)
    params = {} if builder is None else inspect.signature(builder).parameters
    takes = [
        name
        for name, p in params.items()
        if p.kind is p.KEYWORD_ONLY and name not in ("episodes", "workers", "progress", "check")
    ]
    unknown = sorted(set(kwargs) - set(takes))
    if unknown:
        near = [m for u in unknown for m in difflib.get_close_matches(u, takes + own, n=1)]
        raise DatasetArgumentError(
            f"{spec.id}'s dataset takes no argument {', '.join(map(repr, unknown))}",
            (f"did you mean {', '.join(map(repr, near))}? " if near else "") + f"it takes {', '.join(own + takes)}",
        )
    if "check" in params:  # a builder that can check its values without work (d5rl's own do)
        builder(spec, None, None, episodes=0, check=True, **kwargs)


def _repair_hint(spec: TaskSpec, dspec) -> str:
    if dspec.imported:
        return resolve(dspec.importer).how
    return f"run `d5rl generate {spec.id}` (it regenerates damaged shards and keeps the rest)"


def _manifest(path: Path, spec: TaskSpec, dspec) -> dict:
    try:
        return fmt.read_manifest(path)
    except DatasetCorruptError as e:
        raise _NotReady(DatasetCorruptError(e.message, _repair_hint(spec, dspec)), True) from None


def _open(
    spec: TaskSpec,
    dspec,
    *,
    seed: int,
    root: Path,
    wanted: int,
    partial: bool,
    in_memory: bool | str,
    limit: int,
    obs_keys: list[str] | None,
    workers: int | None,
    progress: bool,
    derived_kwargs: dict,
) -> Dataset:
    """The first ``wanted`` episodes of the dataset at ``root`` (``partial``: fewer than all were asked for),
    derived caches built first; :class:`_NotReady` when it must be generated or repaired first."""
    manifest_path = root / fmt.MANIFEST
    have = _manifest(manifest_path, spec, dspec)["num_episodes"] if manifest_path.exists() else 0
    if have < wanted and dspec.imported:
        raise _NotReady(generation.not_imported_error(spec, dspec))
    if have < wanted:
        raise _NotReady(
            DatasetNotFoundError(
                f"dataset {dspec.name} (seed {seed}) has {have} of the {wanted} episodes asked for in {root}",
                f"run `d5rl generate {spec.id}" + (f" --episodes {wanted}`" if partial else "`"),
            )
        )
    n = wanted
    if dspec.derived is not None:  # build missing caches first (may write; takes the write lock)
        extra_roots = resolve(dspec.derived)(
            spec,
            root,
            _manifest(manifest_path, spec, dspec),
            episodes=n,
            workers=workers,
            progress=progress,
            **derived_kwargs,
        )
    else:
        extra_roots = []
    with lock.reading(root):  # the manifest and the shards below belong together
        manifest = _manifest(manifest_path, spec, dspec)
        generation.check_current(manifest, dspec, seed, root)
        if manifest["num_episodes"] < dspec.num_episodes and not partial:
            warnings.warn(
                f"{dspec.name} has only {manifest['num_episodes']} of its {dspec.num_episodes} episodes "
                f"(generated with --episodes); run `d5rl generate {spec.id}` for the full dataset",
                stacklevel=4,
            )
        repair = _repair_hint(spec, dspec)
        shard_dirs, records = [], []
        for entry in manifest["shards"]:
            if entry["episodes"][0] >= n:
                break
            d = root / "shards" / entry["name"]
            try:
                rec = fmt.read_shard_record(d)
            except (FileNotFoundError, DatasetCorruptError):
                raise _NotReady(DatasetCorruptError(f"shard {d} is missing or unreadable", repair), True) from None
            if rec["arrays"] != entry["arrays"] and not _extends(rec, entry, manifest):
                raise _NotReady(DatasetCorruptError(f"shard {d} does not match the manifest", repair), True)
            problems = fmt.check_shard(d, rec)
            if problems:
                raise _NotReady(DatasetCorruptError(f"damaged shard: {problems[0]}", repair), True)
            shard_dirs.append(d)
            records.append(rec)
        last = records[-1]["episodes"]
        n_last = n - last[0] if n < last[1] else None
        chunks, aligns = _shard_chunks(shard_dirs, records, n_last)
        for extra in extra_roots:
            extra_dirs = [Path(extra) / d.name for d in shard_dirs]
            extra_records = []
            for d, rec in zip(extra_dirs, records):
                try:
                    ex = fmt.read_shard_record(d)
                except (FileNotFoundError, DatasetCorruptError):
                    raise _NotReady(
                        DatasetCorruptError(f"cache shard {d} is missing or unreadable", repair), True
                    ) from None
                problems = fmt.check_shard(d, ex)
                if problems or ex.get("source_states_sha256") != rec["arrays"]["states"]["sha256"]:
                    raise _NotReady(
                        DatasetCorruptError(f"damaged cache shard: {problems[0] if problems else d}", repair), True
                    )
                extra_records.append(ex)
            c, a = _shard_chunks(extra_dirs, extra_records, n_last)
            chunks.update(c)
            aligns.update(a)

        arrays: dict[str, Any] = {}
        for key, parts in chunks.items():
            arr = ChunkedArray(parts)
            load = in_memory is True or (in_memory == "auto" and arr.nbytes <= limit)
            arrays[key] = np.asarray(arr) if load else (parts[0] if len(parts) == 1 else arr)
    lengths = np.array([x for r in records for x in r["episode_lengths"]][:n])
    meta = [m for r in records for m in r["episode_meta"]][:n]
    if spec.relabel is not None:
        arrays.update(resolve(spec.relabel)(spec, arrays))
    metadata = {**{k: v for k, v in manifest.items() if k != "shards"}, "task_id": spec.id, "root": str(root)}
    if obs_keys is None and spec.observation == "state" and "observations" in arrays:
        obs_keys = ["observations"]  # a "-state" twin of a camera task: the flat state vector only
        # (without its cache, render=False: the stored observations, as for its camera task)
    return Dataset(arrays, aligns, lengths, meta, metadata, obs_keys=obs_keys)
