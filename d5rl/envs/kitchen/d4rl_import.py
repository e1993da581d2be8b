"""``d5rl import-d4rl-kitchen FILE``: turn an original D4RL kitchen HDF5 file into a d5rl dataset.

D4RL's kitchen files (``kitchen_{complete,partial,mixed}-v0.hdf5``) hold 60-D state
observations: 9 robot joint positions, 21 object joint positions, then a 30-D goal.
We replay those joint positions in our scene (velocities are not stored, so they are
zero), store them as simulator states, and render our cameras from them into the
standard render cache.  Episodes end at ``terminals`` or ``timeouts`` flags (the file's
last episode ends with the file).  Rewards are recomputed for the chosen task
(``--task``) from per-step subtask completion, which is stored too.

    d5rl import-d4rl-kitchen kitchen_mixed-v0.hdf5 --size 64
    ds = d5rl.envs.kitchen.d4rl_import.load_imported("~/.cache/d5rl/datasets/kitchen-d4rl/kitchen_mixed-v0")
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np

from d5rl.datasets import format as fmt
from d5rl.envs.base import STATE_SPEC
from d5rl.envs.kitchen.subtasks import MIXED, PARTIAL, SUBTASK_NAMES, CompletionChecker
from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.files import dump_json

NAME = "kitchen-d4rl"
TASKS = {"mixed": MIXED, "partial": PARTIAL}


def _episode_bounds(terminals: np.ndarray, timeouts: np.ndarray, n: int) -> list[tuple[int, int]]:
    ends = np.flatnonzero(np.asarray(terminals, bool) | np.asarray(timeouts, bool)) + 1
    bounds, start = [], 0
    for e in list(ends) + ([n] if (len(ends) == 0 or ends[-1] != n) else []):
        if e > start:
            bounds.append((start, int(e)))
        start = int(e)
    return bounds


def _check_source(path: Path, obs, actions, terminals, timeouts) -> None:
    """One-line errors for a file that cannot be a D4RL kitchen dataset, before anything is written."""
    n = len(obs)
    hint = "this does not look like an intact D4RL kitchen file"
    if n < 2:
        raise D5RLError(f"{path}: {n} observation rows; an episode needs at least 2", hint)
    for name, arr in (("actions", actions), ("terminals", terminals), ("timeouts", timeouts)):
        if len(arr) != n:
            raise D5RLError(f"{path}: {name} has {len(arr)} rows, observations have {n}", hint)
    if actions.ndim != 2 or actions.shape[1] != 9:
        raise D5RLError(f"{path}: actions have shape {actions.shape}, expected (N, 9)", hint)
    for name, arr in (("observations", obs[:, :30]), ("actions", actions)):
        bad = ~np.isfinite(np.asarray(arr, np.float64))
        if bad.any():
            row = int(np.flatnonzero(bad.any(axis=1))[0])
            raise D5RLError(f"{path}: {name} has {int(bad.sum())} NaN or infinite values (first in row {row})", hint)


def _states_from_qpos(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    out = np.empty((len(qpos), mujoco.mj_stateSize(model, STATE_SPEC)))
    for i, q in enumerate(qpos):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = q
        mujoco.mj_getState(model, data, out[i], STATE_SPEC)
    return out


def import_file(path: str | Path, out: str | Path | None = None, *, task: str = "mixed", cameras=("overview", "wrist"),
                size: int = 64, episodes_per_shard: int = 16, workers: int | None = None,
                progress: bool = True) -> Path:
    """Convert ``path``; returns the dataset directory (states + render cache)."""
    try:
        import h5py
    except ImportError as e:
        raise MissingDependencyError("reading HDF5 needs h5py", "pip install 'd5rl[export]' (or h5py)") from e
    from d5rl import paths
    from d5rl.envs.kitchen import model as km
    from d5rl.envs.kitchen.data import renders

    path = Path(path).expanduser()
    if not path.is_file():
        raise D5RLError(f"no such file: {path}", "pass the path of a D4RL kitchen .hdf5 file")
    if task not in TASKS:
        raise D5RLError(f"unknown task {task!r}", f"choose one of {sorted(TASKS)}")
    renders(None, None, None, episodes=0, cameras=cameras, size=size, check=True)  # before replaying the file
    root = Path(out).expanduser() if out else paths.datasets_dir() / NAME / path.stem
    model = km.build_model()
    checker = CompletionChecker(model)
    cols = [SUBTASK_NAMES.index(t) for t in TASKS[task]]
    with h5py.File(path, "r") as f:
        for key in ("observations", "actions"):
            if key not in f:
                raise D5RLError(f"{path} has no {key!r} array", "this does not look like a D4RL kitchen file")
        obs = np.asarray(f["observations"])
        if obs.ndim != 2 or obs.shape[1] < 30:
            raise D5RLError(f"{path}: observations have shape {obs.shape}, expected (N, 60)",
                            "this does not look like a D4RL kitchen file")
        actions = np.asarray(f["actions"], dtype=np.float32)
        n = len(obs)
        terminals = np.asarray(f["terminals"]) if "terminals" in f else np.zeros(n, bool)
        timeouts = np.asarray(f["timeouts"]) if "timeouts" in f else np.zeros(n, bool)
    _check_source(path, obs, actions, terminals, timeouts)
    bounds = _episode_bounds(terminals, timeouts, n)
    (root / "shards").mkdir(parents=True, exist_ok=True)
    shards = []
    for s, first in enumerate(range(0, len(bounds), episodes_per_shard)):
        group = bounds[first : first + episodes_per_shard]
        parts: dict[str, list[np.ndarray]] = {}
        lengths, metas = [], []
        for a, b in group:
            # An episode of rows a..b-1: observation i, action i.  The last row has no successor,
            # so each imported episode has b-a-1 transitions and b-a states.
            qpos = obs[a:b, :30].astype(np.float64)
            t = b - a - 1
            if t < 1:
                continue
            done = checker.completed(qpos[1:])
            ep = {
                "observations/proprio": qpos[:, :9].astype(np.float32),
                "states": _states_from_qpos(model, qpos),
                "actions": actions[a : b - 1],
                "rewards": done[:, cols].sum(axis=1).astype(np.float32),
                "terminals": np.zeros(t, bool),
                "timeouts": np.eye(1, t, t - 1, dtype=bool)[0],
                "infos/completed": done,
            }
            for k, v in ep.items():
                parts.setdefault(k, []).append(v)
            lengths.append(t)
            metas.append({"source_rows": [int(a), int(b)]})
        if not lengths:
            continue
        writer = fmt.ShardWriter(root / "shards", s)
        aligns = {}
        for k, v in parts.items():
            writer.write(k, np.concatenate(v))
            aligns[k] = "step" if k in ("states", "observations/proprio") else "transition"
        start = shards[-1]["episodes"][1] if shards else 0
        rec = writer.commit({"episodes": [start, start + len(lengths)], "episode_lengths": lengths,
                             "episode_meta": metas}, aligns)
        shards.append({"name": rec["name"], "episodes": rec["episodes"], "arrays": rec["arrays"]})
    manifest = {
        "format_version": fmt.FORMAT_VERSION,
        "dataset": NAME,
        "source_file": path.name,
        "source_sha256": fmt.sha256_file(path),
        "task": task,
        "num_episodes": shards[-1]["episodes"][1] if shards else 0,
        "shards": shards,
    }
    dump_json(manifest, root / fmt.MANIFEST)
    renders(None, root, manifest, episodes=manifest["num_episodes"], workers=workers, progress=progress,
            cameras=tuple(cameras), size=size)
    return root


def load_imported(root: str | Path, cameras=("overview", "wrist"), size: int = 64, **kwargs):
    """Open an imported dataset (rendering the requested cameras first if needed)."""
    from d5rl.datasets.dataset import Dataset
    from d5rl.datasets.loading import _shard_chunks
    from d5rl.envs.kitchen.data import renders

    root = Path(root).expanduser()
    manifest = fmt.load_json(root / fmt.MANIFEST, "manifest")
    n = manifest["num_episodes"]
    dirs = [root / "shards" / e["name"] for e in manifest["shards"]]
    records = [fmt.read_shard_record(d) for d in dirs]
    chunks, aligns = _shard_chunks(dirs, records, None)
    for extra in renders(None, root, manifest, episodes=n, cameras=tuple(cameras), size=size, **kwargs):
        ex_dirs = [Path(extra) / d.name for d in dirs]
        c, a = _shard_chunks(ex_dirs, [fmt.read_shard_record(d) for d in ex_dirs], None)
        chunks.update(c)
        aligns.update(a)
    arrays = {k: np.concatenate(v) for k, v in chunks.items()}
    lengths = [x for r in records for x in r["episode_lengths"]]
    meta = [m for r in records for m in r["episode_meta"]]
    return Dataset(arrays, aligns, np.array(lengths), meta, {"root": str(root), **{k: v for k, v in manifest.items()
                                                                                     if k != "shards"}})


def add_import_d4rl_kitchen_parser(subparsers) -> None:
    q = subparsers.add_parser("import-d4rl-kitchen",
                              help="replay an original D4RL kitchen .hdf5 file and render our cameras into a d5rl dataset")
    q.add_argument("file", help="kitchen_{complete,partial,mixed}-v0.hdf5 from D4RL")
    q.add_argument("--out", default=None, help="output directory (default $D5RL_HOME/datasets/kitchen-d4rl/<stem>)")
    q.add_argument("--task", default="mixed", choices=sorted(TASKS), help="whose rewards to store")
    q.add_argument("--size", type=int, default=64, help="image size (64 or 128)")
    q.add_argument("--cameras", default="overview,wrist", help="comma-separated cameras")
    q.add_argument("--workers", type=int, default=None, help="render processes (default: all cores)")
    q.set_defaults(func=_cmd_import)


def _cmd_import(args: argparse.Namespace) -> int:
    root = import_file(args.file, args.out, task=args.task, cameras=tuple(args.cameras.split(",")), size=args.size,
                       workers=args.workers)
    print(f"wrote {root}")
    return 0
