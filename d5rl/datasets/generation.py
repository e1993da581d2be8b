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
import sys
import time
from pathlib import Path

import numpy as np

from d5rl import numerics, parallel, paths
from d5rl.datasets import format as fmt
from d5rl.datasets import lock
from d5rl.datasets.episode import Episode
from d5rl.errors import D5RLError, DatasetCorruptError, DatasetNotFoundError, DatasetVersionError, is_int
from d5rl.files import dump_json, json_default
from d5rl.progress import progress_bar
from d5rl.registry import DatasetSpec, TaskSpec, get_spec, resolve

MAX_SEED = 2**63 - 1


def dataset_root(dspec: DatasetSpec, seed: int | None = None) -> Path:
    seed = dspec.default_seed if seed is None else int(seed)
    return paths.datasets_dir() / dspec.name / f"v{dspec.version}-seed{seed}"


def dataset_spec(task: str | TaskSpec) -> DatasetSpec:
    spec = get_spec(task)
    if spec.dataset is None:
        raise D5RLError(f"task {spec.id} has no offline dataset")
    if spec.dataset.unavailable:
        raise D5RLError(f"{spec.id}: {spec.dataset.unavailable}")
    return spec.dataset


def full_size(dspec: DatasetSpec) -> int:
    """The dataset's number of episodes: as specified, or for an imported one as imported (0 if not)."""
    if not dspec.imported:
        return dspec.num_episodes
    path = dataset_root(dspec) / fmt.MANIFEST
    try:
        return int(fmt.read_manifest(path)["num_episodes"]) if path.exists() else 0
    except D5RLError:
        return 0


def not_imported_error(spec: TaskSpec, dspec: DatasetSpec) -> D5RLError:
    """The one-line error for an imported dataset that is not on disk (d5rl cannot make it)."""
    how = resolve(dspec.importer).how
    return DatasetNotFoundError(
        f"{spec.id} trains on imported data ({dspec.name}), which is not in {dataset_root(dspec)}", how
    )


def check_seed(seed) -> int:
    """A dataset seed, checked before any work: an integer in [0, 2**63)."""
    if not is_int(seed, lo=0, hi=MAX_SEED):
        raise D5RLError(
            f"dataset seed must be an integer in [0, 2**63), got {seed!r}",
            "omit --seed (seed= in Python) to use the task's default seed (0)",
        )
    return int(seed)


def check_episodes(episodes, dspec: DatasetSpec) -> int:
    """A number of episodes, checked before any work: 1 ..= the dataset's full size."""
    if episodes is None:
        return dspec.num_episodes
    if not is_int(episodes, lo=1, hi=dspec.num_episodes):
        raise D5RLError(
            f"{dspec.name} has {dspec.num_episodes} episodes; {episodes!r} were asked for",
            f"ask for 1 to {dspec.num_episodes} episodes (omit --episodes, or episodes= in Python, for all of them)",
        )
    return int(episodes)


def episode_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of episode ``index``: independent of every other episode."""
    return np.random.default_rng([int(seed), int(index)])


def shard_plan(num_episodes: int, per_shard: int) -> list[tuple[int, int]]:
    return [(a, min(a + per_shard, num_episodes)) for a in range(0, num_episodes, per_shard)]


def _identity(dspec: DatasetSpec, seed: int, generator_version: str) -> dict:
    """What every shard and the manifest must agree on for data to be reused (as stored in JSON).

    A generator that replays files outside the code (the A1 agents' policy snapshots) names them by
    digest through an ``inputs(**generator_kwargs)`` static method: data made from other files (e.g.
    trial policies under ``D5RL_A1_POLICIES``) then never pass for the data of the published ones."""
    ident = {
        "dataset": dspec.name,
        "dataset_version": dspec.version,
        "generator": producer_name(dspec),
        "generator_version": generator_version,
        "generator_kwargs": dspec.generator_kwargs,
        "seed": seed,
    }
    inputs = getattr(resolve(dspec.producer), "inputs", None)
    if inputs is not None and not dspec.unavailable:
        digests = inputs(**dspec.generator_kwargs)
        if digests:  # absent rather than empty, so data without such inputs keep their identity
            ident["generator_inputs"] = digests
    return _json_normal(ident)


def producer_name(dspec: DatasetSpec) -> str:
    """The name a dataset's manifest and shards give the code that writes it (its generator, or its importer):
    the producer's ``name`` where it sets one, the "module:Class" it was first published under, kept when the
    code moves so that data already made stay current; else ``DatasetSpec.generator`` / ``importer``."""
    return getattr(resolve(dspec.producer), "name", dspec.producer)


def identity(dspec: DatasetSpec, seed: int | None = None) -> dict:
    """What the manifest and every shard of ``dspec``'s data written by this code carry (an importer
    writes it too, so the loader checks imported data like generated data)."""
    seed = dspec.default_seed if seed is None else int(seed)
    return _identity(dspec, seed, str(resolve(dspec.producer).version))


def _json_normal(obj):
    """``obj`` as it reads back from JSON (tuples become lists), so comparisons with disk are exact."""
    import json

    return json.loads(json.dumps(obj, default=json_default))


# --- worker side -------------------------------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(spec: TaskSpec) -> None:
    _WORKER.clear()
    numerics.require(dataset_spec(spec).numerics)
    _WORKER["numerics"] = numerics.current()
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
            "numerics": _WORKER["numerics"],
            "episode_lengths": [ep.num_transitions for ep in episodes],
            "episode_meta": [ep.meta for ep in episodes],
        }
        return writer.commit(meta, aligns)
    except BaseException:
        writer.abort()
        raise


# --- what a result was trained on --------------------------------------------------------------------
# The part of a dataset's identity that decides its content (a result trained on data that differs in any
# of these describes other data); "generator_inputs" too where the generator has them.
RESULT_IDENTITY_KEYS = ("dataset", "dataset_version", "generator_version", "seed")


def result_identity(meta: dict) -> dict:
    """The :data:`RESULT_IDENTITY_KEYS` of a dataset's identity or metadata, with its generator inputs where
    it has them."""
    return {k: meta[k] for k in (*RESULT_IDENTITY_KEYS, "generator_inputs") if k in meta}


def data_identity(task: str | TaskSpec, seed: int | None = None) -> dict | None:
    """What ``task``'s dataset is when this d5rl generates it (at ``seed``, default the dataset's):
    :func:`result_identity` of its identity; None for a task without a dataset."""
    spec = get_spec(task)
    if spec.dataset is None:
        return None
    dspec = spec.dataset
    seed = dspec.default_seed if seed is None else int(seed)
    ident = _identity(dspec, seed, str(resolve(dspec.producer).version))
    return result_identity(ident)


def stale_data(task: str, recorded: dict | None) -> str | None:
    """Why a result trained on the dataset ``recorded`` (a :func:`data_identity`, as a run's config.json
    keeps it) no longer describes ``task``'s data, or None when it still does (or nothing was recorded)."""
    if not recorded:
        return None
    try:
        now = data_identity(task, recorded.get("seed"))
    except D5RLError:  # a task only a custom job knows
        return None
    if now is None:
        return None
    # a record without generator inputs (made before runs kept them) cannot tell which inputs it had
    diffs = [k for k in now if recorded.get(k) != now[k] and (k != "generator_inputs" or k in recorded)]
    if not diffs:
        return None
    if diffs == ["generator_inputs"]:
        return (
            f"trained on {recorded.get('dataset')} made from other generator inputs than the published "
            f"ones ({', '.join(sorted(now['generator_inputs']))})"
        )
    return (
        f"trained on {recorded.get('dataset')} v{recorded.get('dataset_version')} "
        f"(generator {recorded.get('generator_version')}); the task's data is now "
        f"{now['dataset']} v{now['dataset_version']} (generator {now['generator_version']})"
    )


# --- driver side -------------------------------------------------------------------------------------
def check_current(manifest: dict, dspec: DatasetSpec, seed: int, where: Path) -> None:
    """Raise :class:`DatasetVersionError` unless ``manifest`` was written by this code and settings."""
    hint = resolve(dspec.importer).how if dspec.imported else None
    _check_identity(manifest, _identity(dspec, seed, str(resolve(dspec.producer).version)), where, hint)


def _check_identity(found: dict, ident: dict, where: Path, hint: str | None = None) -> None:
    diffs = [k for k in ident if found.get(k) != ident[k]]
    if diffs:
        detail = ", ".join(f"{k}: on disk {found.get(k)!r}, now {ident[k]!r}" for k in diffs)
        raise DatasetVersionError(
            f"{where} was generated by different code or settings ({detail})",
            hint or "regenerate it with `d5rl generate TASK --force`",
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
    """Generate, finish, extend or repair a task's dataset; return its directory.

    Intact shards are kept (checked by checksum, or by file stats since their last check), so
    calling this after an interruption continues where the last run stopped, and missing or
    damaged shards of a finished dataset are regenerated (deterministically: the same bytes).
    ``force`` deletes what is there first.  One process writes a dataset at a time: a second
    call waits for the first, then finds its work done.
    """
    spec = get_spec(task)
    dspec = dataset_spec(spec)
    if dspec.imported:
        raise D5RLError(f"{spec.id}'s dataset {dspec.name} is imported, not generated", resolve(dspec.importer).how)
    seed = check_seed(dspec.default_seed if seed is None else seed)
    num_episodes = check_episodes(num_episodes, dspec)
    parallel.check_workers(workers)
    root = dataset_root(dspec, seed)
    fmt.ensure_writable(root)
    with lock.writing(root):
        try:
            return _generate_locked(spec, dspec, seed, num_episodes, root, workers, force, progress)
        except OSError as e:
            full = fmt.disk_full_error(root, e)
            if full is not None:
                raise full from None
            raise


def _generate_locked(spec, dspec, seed, num_episodes, root, workers, force, progress) -> Path:
    shards_dir = root / "shards"
    if force:
        with lock.publishing(root):
            (root / fmt.MANIFEST).unlink(missing_ok=True)
            for sub in ("shards", "renders"):
                shutil.rmtree(root / sub, ignore_errors=True)
    shards_dir.mkdir(parents=True, exist_ok=True)
    fmt.clean_temporaries(shards_dir)

    generator_version = str(resolve(dspec.producer).version)
    ident = _identity(dspec, seed, generator_version)
    manifest_path = root / fmt.MANIFEST
    manifest, repairs = None, []
    if manifest_path.exists():
        try:
            manifest = fmt.read_manifest(manifest_path)
        except DatasetCorruptError as e:  # rebuilt below from the shards, which carry everything it lists
            repairs.append(f"{fmt.MANIFEST} ({e.message.split(': ', 1)[-1]})")
        else:
            _check_identity(manifest, ident, root)
    have = manifest["num_episodes"] if manifest is not None else 0
    # never shrink what the manifest (or, when it is damaged, the shards on disk) already promise
    target = max(num_episodes, have if manifest is not None else _episodes_on_disk(shards_dir, dspec, ident))
    listed = {e["name"]: e for e in manifest["shards"]} if manifest is not None else {}

    plan = shard_plan(target, dspec.episodes_per_shard)
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
                entry = listed.get(shard_dir.name)
                if rec["episodes"] == [start, stop]:
                    problems = fmt.check_shard(shard_dir, rec)
                    if (
                        not problems
                        and entry is not None
                        and entry["episodes"] == rec["episodes"]
                        and entry["arrays"] != rec["arrays"]
                    ):
                        # The shard's record and the manifest disagree and either may be the damaged one:
                        # generation is deterministic, so the regenerated shard settles it.
                        problems = [f"{fmt.SHARD_META} disagrees with {fmt.MANIFEST}"]
                    if not problems:
                        records[index] = rec
                        continue
                    repairs.append(f"{shard_dir.name} ({problems[0].rsplit('/', 1)[-1]})")
            elif stop <= have:
                repairs.append(f"{shard_dir.name} (unreadable {fmt.SHARD_META})")
        elif stop <= have:
            repairs.append(f"{shard_dir.name} (missing)")
        pending.append((index, start, stop))
    # Shards beyond the plan belong to a larger earlier request; they stay valid and are kept.
    if not pending and have == target:
        if manifest_content(manifest) == manifest_content(
            build_manifest(dspec, ident, [records[i] for i in range(len(plan))], target)
        ):
            return root
        repairs.append(f"{fmt.MANIFEST} (disagrees with the shards)")
    if repairs:
        print(
            f"repairing {len(repairs)} damaged or missing part(s) of {dspec.name}: {', '.join(repairs[:5])}"
            + (" ..." if len(repairs) > 5 else ""),
            file=sys.stderr,
            flush=True,
        )

    done_eps = sum(stop - start for i, (start, stop) in enumerate(plan) if i in records)
    bar = progress_bar(
        total=target,
        initial=done_eps,
        unit="ep",
        desc=f"generate {dspec.name}",
        disable=not progress,
        dynamic_ncols=True,
    )
    t0, transitions = time.perf_counter(), 0

    def on_message(n_transitions: int) -> None:
        nonlocal transitions
        transitions += n_transitions
        bar.update(1)
        bar.set_postfix(steps_per_s=f"{transitions / max(time.perf_counter() - t0, 1e-9):.0f}", refresh=False)

    def on_result(i: int, record: dict) -> None:
        records[pending[i][0]] = record

    if dspec.numerics == "portable" and not numerics.supported():
        print(
            f"warning: {dspec.name} is defined with portable numerics, which this platform does not have; "
            "its bytes may differ from the reference's",
            file=sys.stderr,
            flush=True,
        )
    try:
        parallel.run_jobs(
            _run_shard,
            [(str(shards_dir), index, start, stop, ident) for index, start, stop in pending],
            workers=workers,
            initializer=_init_worker,
            initargs=(spec,),
            on_message=on_message,
            on_result=on_result,
            shared_dir=shards_dir,
            worker_env=numerics.worker_env(dspec.numerics),
        )
    finally:
        bar.close()
        fmt.clean_temporaries(shards_dir)  # workers are gone: remove what an interrupted one left

    write_manifest(root, dspec, ident, [records[i] for i in range(len(plan))], target)
    return root


def _episodes_on_disk(shards_dir: Path, dspec: DatasetSpec, ident: dict) -> int:
    """How many episodes the readable shards of this dataset hold, counted from the first without a gap
    (what a damaged manifest listed, at least)."""
    end = 0
    for index, (start, stop) in enumerate(shard_plan(dspec.num_episodes, dspec.episodes_per_shard)):
        try:
            rec = fmt.read_shard_record(shards_dir / fmt.shard_name(index))
        except (FileNotFoundError, D5RLError):
            return end
        if any(rec.get(k) != v for k, v in ident.items()) or rec["episodes"][0] != start:
            return end
        end = rec["episodes"][1]
        if end < stop:
            return end
    return end


def manifest_content(manifest: dict | None) -> dict | None:
    """What a manifest says about the data (not the package versions that wrote it)."""
    return None if manifest is None else {k: v for k, v in manifest.items() if k != "packages"}


def build_manifest(
    dspec: DatasetSpec, ident: dict, records: list[dict], num_episodes: int, extra: dict | None = None
) -> dict:
    """The manifest of finished shards; ``extra``: more keys (an importer's source and replay check)."""
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
        # "portable" only if every shard was written by a portable process (shards of older d5rl: native)
        "numerics": "portable" if all(r.get("numerics") == "portable" for r in records) else "native",
        "arrays": arrays,
        "shards": [{k: r[k] for k in ("name", "episodes", "arrays")} for r in records],
        "packages": fmt.package_versions(),
        **(extra or {}),
    }
    return _json_normal(manifest)


def write_manifest(
    root: Path, dspec: DatasetSpec, ident: dict, records: list[dict], num_episodes: int, extra: dict | None = None
) -> dict:
    """Publish the manifest of finished shards (see :func:`build_manifest`)."""
    manifest = build_manifest(dspec, ident, records, num_episodes, extra)
    with lock.publishing(root):  # replaces the old manifest (if extending) in one step
        dump_json(manifest, root / fmt.MANIFEST)
    return manifest
