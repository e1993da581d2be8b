"""Deterministic, resumable, parallel dataset generation.

Episode ``i`` of a dataset generated with seed ``s`` is produced by
``generator.episode(i, np.random.default_rng([s, i]))`` – a pure function, so
the bytes do not depend on the number of workers, the order shards finish, or
whether the run was interrupted.  Episodes are grouped in shards of
``DatasetSpec.episodes_per_shard``; each shard is written atomically (see
:mod:`d5rl.datasets.format`), so a killed run resumes at the first missing shard.
A smaller dataset is a prefix of a bigger one with the same seed: generating
more episodes later extends it.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from d5rl import parallel, paths
from d5rl.datasets import format as fmt
from d5rl.datasets.episode import Episode
from d5rl.errors import D5RLError, DatasetVersionError
from d5rl.registry import DatasetSpec, TaskSpec, get_spec, resolve


def dataset_root(dspec: DatasetSpec, seed: int | None = None) -> Path:
    seed = dspec.default_seed if seed is None else int(seed)
    return paths.datasets_dir() / dspec.name / f"v{dspec.version}-seed{seed}"


def dataset_spec(task: str | TaskSpec) -> DatasetSpec:
    spec = get_spec(task)
    if spec.dataset is None:
        raise D5RLError(f"task {spec.id} has no offline dataset")
    return spec.dataset


def episode_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of episode ``index``: independent of every other episode."""
    return np.random.default_rng([int(seed), int(index)])


def shard_plan(num_episodes: int, per_shard: int) -> list[tuple[int, int]]:
    return [(a, min(a + per_shard, num_episodes)) for a in range(0, num_episodes, per_shard)]


def _identity(dspec: DatasetSpec, seed: int, generator_version: str) -> dict:
    """What every shard and the manifest must agree on for data to be reused (as stored in JSON)."""
    return _json_normal({
        "dataset": dspec.name,
        "dataset_version": dspec.version,
        "generator": dspec.generator,
        "generator_version": generator_version,
        "generator_kwargs": dspec.generator_kwargs,
        "seed": seed,
    })


def _json_normal(obj):
    """``obj`` as it reads back from JSON (tuples become lists), so comparisons with disk are exact."""
    import json

    return json.loads(json.dumps(obj, default=fmt._json_default))


# --- worker side -------------------------------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(spec: TaskSpec) -> None:
    _WORKER.clear()
    _WORKER["generator"] = make_generator(spec)


def make_generator(task: str | TaskSpec):
    spec = get_spec(task)
    dspec = dataset_spec(spec)
    cls = resolve(dspec.generator)
    return cls(task_id=spec.id, **dspec.generator_kwargs)


def _concat(episodes: list[Episode]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    keys = sorted(episodes[0].arrays)
    arrays, aligns = {}, {}
    for ep_i, ep in enumerate(episodes):
        if sorted(ep.arrays) != keys:
            raise ValueError(f"episode {ep_i} of the shard has arrays {sorted(ep.arrays)}, the first had {keys}")
    for key in keys:
        parts = [ep.arrays[key] for ep in episodes]
        first = parts[0]
        for p in parts[1:]:
            if p.dtype != first.dtype or p.shape[1:] != first.shape[1:]:
                raise ValueError(f"array {key!r}: {p.dtype}{p.shape[1:]} differs from {first.dtype}{first.shape[1:]}")
        step = [len(p) == ep.num_transitions + 1 for p, ep in zip(parts, episodes)]
        if len(set(step)) != 1:
            raise ValueError(f"array {key!r} is step-aligned in some episodes and transition-aligned in others")
        arrays[key] = np.concatenate(parts, axis=0)
        aligns[key] = "step" if step[0] else "transition"
    return arrays, aligns


def _run_shard(root: str, index: int, start: int, stop: int, ident: dict) -> dict:
    gen = _WORKER["generator"]
    episodes = []
    for i in range(start, stop):
        ep = gen.episode(i, episode_rng(ident["seed"], i))
        ep.validate()
        if ep.num_transitions < 1:
            raise ValueError(f"episode {i} has no transitions")
        episodes.append(ep)
        parallel.report(ep.num_transitions)
    arrays, aligns = _concat(episodes)
    writer = fmt.ShardWriter(Path(root), index)
    try:
        for key, arr in arrays.items():
            writer.write(key, arr)
        meta = {
            **ident,
            "episodes": [start, stop],
            "episode_lengths": [ep.num_transitions for ep in episodes],
            "episode_meta": [ep.meta for ep in episodes],
        }
        return writer.commit(meta, aligns)
    except BaseException:
        writer.abort()
        raise


# --- driver side -------------------------------------------------------------------------------------
def check_current(manifest: dict, dspec: DatasetSpec, seed: int, where: Path) -> None:
    """Raise :class:`DatasetVersionError` unless ``manifest`` was written by this code and settings."""
    _check_identity(manifest, _identity(dspec, seed, str(resolve(dspec.generator).version)), where)


def _check_identity(found: dict, ident: dict, where: Path) -> None:
    diffs = [k for k in ident if found.get(k) != ident[k]]
    if diffs:
        detail = ", ".join(f"{k}: on disk {found.get(k)!r}, now {ident[k]!r}" for k in diffs)
        raise DatasetVersionError(
            f"{where} was generated by different code or settings ({detail})",
            "regenerate it with `d5rl generate TASK --force`",
        )


def generate(
    task: str | TaskSpec,
    *,
    seed: int | None = None,
    num_episodes: int | None = None,
    workers: parallel.Workers = None,
    force: bool = False,
    progress: bool = True,
) -> Path:
    """Generate (or finish, or extend) a task's dataset; return its directory.

    Already-complete shards are kept, so calling this after an interruption
    continues where the last run stopped.  ``force`` deletes what is there first.
    """
    spec = get_spec(task)
    dspec = dataset_spec(spec)
    seed = dspec.default_seed if seed is None else int(seed)
    num_episodes = dspec.num_episodes if num_episodes is None else int(num_episodes)
    if num_episodes < 1:
        raise D5RLError(f"num_episodes must be >= 1, got {num_episodes}")
    root = dataset_root(dspec, seed)
    if force and root.exists():
        shutil.rmtree(root)
    shards_dir = root / "shards"
    shards_dir.mkdir(parents=True, exist_ok=True)
    fmt.clean_temporaries(shards_dir)

    generator_version = str(resolve(dspec.generator).version)
    ident = _identity(dspec, seed, generator_version)
    manifest_path = root / fmt.MANIFEST
    if manifest_path.exists():
        manifest = fmt.load_json(manifest_path, "manifest")
        _check_identity(manifest, ident, root)
        if manifest["num_episodes"] >= num_episodes:
            return root
        manifest_path.unlink()  # about to extend: the dataset is incomplete until the new manifest lands

    plan = shard_plan(num_episodes, dspec.episodes_per_shard)
    records: dict[int, dict] = {}
    pending = []
    for index, (start, stop) in enumerate(plan):
        shard_dir = shards_dir / fmt.shard_name(index)
        if shard_dir.exists():
            try:
                rec = fmt.read_shard_record(shard_dir)
            except (FileNotFoundError, D5RLError):
                rec = None
            if rec is not None:
                _check_identity(rec, ident, shard_dir)
                if rec["episodes"] == [start, stop]:
                    records[index] = rec
                    continue
        pending.append((index, start, stop))
    # Shards beyond the plan belong to a larger earlier request; they stay valid and are kept.

    done_eps = sum(stop - start for i, (start, stop) in enumerate(plan) if i in records)
    bar = tqdm(
        total=num_episodes, initial=done_eps, unit="ep", desc=f"generate {dspec.name}",
        disable=not progress, dynamic_ncols=True,
    )
    t0, transitions = time.perf_counter(), 0

    def on_message(n_transitions: int) -> None:
        nonlocal transitions
        transitions += n_transitions
        bar.update(1)
        bar.set_postfix(steps_per_s=f"{transitions / max(time.perf_counter() - t0, 1e-9):.0f}", refresh=False)

    def on_result(i: int, record: dict) -> None:
        records[pending[i][0]] = record

    try:
        parallel.run_jobs(
            _run_shard, [(str(shards_dir), index, start, stop, ident) for index, start, stop in pending],
            workers=workers, initializer=_init_worker, initargs=(spec,),
            on_message=on_message, on_result=on_result, shared_dir=shards_dir,
        )
    finally:
        bar.close()

    write_manifest(root, dspec, ident, [records[i] for i in range(len(plan))], num_episodes)
    return root


def write_manifest(root: Path, dspec: DatasetSpec, ident: dict, records: list[dict], num_episodes: int) -> dict:
    lengths = [n for r in records for n in r["episode_lengths"]]
    arrays = {}
    for key, info in records[0]["arrays"].items():
        arrays[key] = {"dtype": info["dtype"], "shape": info["shape"][1:], "align": info["align"]}
    manifest = {
        **ident,
        "format_version": fmt.FORMAT_VERSION,
        "num_episodes": num_episodes,
        "num_transitions": int(sum(lengths)),
        "episodes_per_shard": dspec.episodes_per_shard,
        "arrays": arrays,
        "shards": [{k: r[k] for k in ("name", "episodes", "arrays")} for r in records],
        "packages": fmt.package_versions(),
    }
    fmt.dump_json(manifest, root / fmt.MANIFEST)
    return manifest
