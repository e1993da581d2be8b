"""The paper's standard-kitchen data: the relay-policy-learning human demonstrations, imported.

The D5RL paper's standard kitchen trains on the RPL human tele-operation demonstrations
re-rendered with its cameras.  They are public in two layouts, and ``d5rl import-kitchen-human
SOURCE`` reads both:

* Minari's ``D4RL/kitchen/{complete,partial,mixed}-v2`` (``minari download D4RL/kitchen/mixed-v2``):
  ``<dataset>/data/main_data.hdf5`` with one group ``episode_<i>`` per demonstration holding
  ``observations/observation`` (T+1, 59): 9 robot joint positions, 9 robot joint velocities, 21 object
  joint positions, 20 object joint velocities, with gymnasium-robotics' uniform observation noise;
  ``observations/achieved_goal/<subtask>`` and ``observations/desired_goal/<subtask>`` (T+1, k) for
  the dataset's four target subtasks (noise-free joint positions); ``actions`` (T, 9); ``rewards``,
  ``terminations``, ``truncations`` (T,).  SOURCE is a Minari dataset id (looked up under
  ``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``), its directory, or its ``main_data.hdf5``.
* D4RL's ``kitchen_*-v0.hdf5``: ``observations`` (N, 60) = 30 joint positions then the 30-D goal
  (zeros but for the target subtasks' joints), ``actions`` (N, 9), ``terminals``/``timeouts`` (N,)
  ending episodes.  No velocities are stored (they are zero here).

Every step's simulator state is restored from the joint positions (and velocities where stored; the
target subtasks' object positions from the noise-free ``achieved_goal``), and the replay is checked:
the subtasks the file says are done (its own goal test on its own values) must be done in our scene,
step by step; mismatches are reported per episode and kept in the manifest (``replay_check``).  Every
tenth transition is also stepped in our env from its stored state with its stored action, and the
distance to the next stored arm position reported: whether the actions mean the same here.  The
result is a regular d5rl dataset (``kitchen-standard-human``: manifest, checksummed shards, states,
``infos/completed``, render cache built from the states) that every standard-kitchen task reads as its
``human`` variant, relabelling rewards for its own four subtasks::

    minari download D4RL/kitchen/mixed-v2
    d5rl import-kitchen-human D4RL/kitchen/mixed-v2
    d5rl train bc kitchen-standard-mixed-state-human-v0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np

from d5rl.datasets import format as fmt
from d5rl.datasets import generation, lock
from d5rl.datasets.loading import load_dataset
from d5rl.envs.base import STATE_SPEC
from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.registration import HUMAN_DATASET
from d5rl.envs.kitchen.subtasks import MIXED, SUBTASK_NAMES, SUBTASKS, THRESHOLD, CompletionChecker
from d5rl.envs.kitchen.task import KitchenEnv
from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.production.kitchen.data import renders
from d5rl.progress import progress_bar

DEFAULT_SOURCE = "D4RL/kitchen/mixed-v2"
# gymnasium-robotics' 59-D observation: robot qpos, robot qvel, object qpos, object qvel
MINARI_QPOS = np.r_[0:9, 18:39]
MINARI_QVEL = np.r_[9:18, 39:59]


class KitchenHumanImport:
    """``DatasetSpec.importer`` of the human data: what identifies the conversion, and how to get it."""

    version = "kitchen-human-import-1"
    name = "d5rl.envs.kitchen.human:KitchenHumanImport"  # in the manifests (the code's first home)
    command = f"d5rl import-kitchen-human {DEFAULT_SOURCE}"
    how = (
        f"download the human demonstrations with `minari download {DEFAULT_SOURCE}` (pip install minari), "
        f"then run `{command}` (a D4RL kitchen .hdf5 file works too)"
    )


@dataclasses.dataclass
class SourceEpisode:
    """One demonstration as the file stores it, in our scene's joint order."""

    qpos: np.ndarray  # (T+1, 30)
    qvel: np.ndarray | None  # (T+1, 29), None where the file stores no velocities
    actions: np.ndarray  # (T, 9)
    claimed: dict[str, np.ndarray]  # subtask -> (T,) bool: in its goal after each transition, per the file
    meta: dict


def _h5py():
    try:
        import h5py
    except ImportError as e:
        raise MissingDependencyError("reading HDF5 needs h5py", "pip install 'd5rl[export]' (or h5py)") from e
    return h5py


# --- finding and reading the source ---------------------------------------------------------------
def minari_root() -> Path:
    env = os.environ.get("MINARI_DATASETS_PATH")
    return Path(env).expanduser() if env else Path.home() / ".minari" / "datasets"


def locate(source: str | Path) -> tuple[str, Path]:
    """``("minari", main_data.hdf5)`` or ``("d4rl", file.hdf5)`` for a path or a Minari dataset id."""
    h5py = _h5py()
    path = Path(source).expanduser()
    if not path.exists() and not Path(str(source)).is_absolute():
        path = minari_root() / str(source)
    if path.is_dir():
        for candidate in (path / "data" / "main_data.hdf5", path / "main_data.hdf5"):
            if candidate.is_file():
                return "minari", candidate
        raise D5RLError(f"{path} holds no Minari dataset (no data/main_data.hdf5)", KitchenHumanImport.how)
    if not path.is_file():
        raise D5RLError(
            f"no kitchen dataset at {source!r} (looked for a file, a directory and a Minari id under {minari_root()})",
            KitchenHumanImport.how,
        )
    try:
        with h5py.File(path, "r") as f:
            keys = list(f.keys())
    except OSError as e:
        raise D5RLError(f"{path} is not an HDF5 file ({e})", KitchenHumanImport.how) from None
    if "observations" in keys:
        return "d4rl", path
    if any(k.startswith("episode_") for k in keys):
        return "minari", path
    raise D5RLError(
        f"{path} has no 'observations' array and no episode_* groups",
        "this does not look like a D4RL kitchen file or a Minari kitchen dataset",
    )


def _episode_bounds(terminals: np.ndarray, timeouts: np.ndarray, n: int) -> list[tuple[int, int]]:
    ends = np.flatnonzero(np.asarray(terminals, bool) | np.asarray(timeouts, bool)) + 1
    bounds, start = [], 0
    for e in list(ends) + ([n] if (len(ends) == 0 or ends[-1] != n) else []):
        if e > start:
            bounds.append((start, int(e)))
        start = int(e)
    return bounds


# The kitchen's files are uncompressed float data (D4RL's ~30 MB); an array may declare at most this many
# times the file's size before it is read, so a few kB claiming gigabytes are refused rather than allocated.
MAX_EXPANSION = 16
MAX_ABS = 1e3  # joint positions (rad, m) and actions of the kitchen are a few units at most


def _read(group, key: str, path: Path, where: str, kinds: str, ndim: int, hint: str, dtype=None) -> np.ndarray:
    """``group[key]`` as an array, after checking its kind, dimensions and declared size (nothing read before)."""
    d = group[key]
    if not isinstance(d, _h5py().Dataset):
        raise D5RLError(f"{where}: {key} is not an array", hint)
    if d.dtype.kind not in kinds:
        raise D5RLError(f"{where}: {key} holds {d.dtype} values, not numbers", hint)
    if len(d.shape) != ndim:
        raise D5RLError(f"{where}: {key} has shape {d.shape}, expected {ndim} dimension(s)", hint)
    declared, size = int(np.prod(d.shape, dtype=np.float64)) * d.dtype.itemsize, path.stat().st_size
    if declared > MAX_EXPANSION * size + (1 << 20):
        raise D5RLError(
            f"{where}: {key} declares shape {d.shape} ({declared / 2**20:,.0f} MiB) in a file of "
            f"{size / 2**20:,.1f} MiB",
            hint,
        )
    return np.asarray(d, dtype)


def _finite(path: Path, name: str, arr: np.ndarray, hint: str, offset: int = 0) -> None:
    a = np.asarray(arr, np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        row = int(np.flatnonzero(bad.reshape(len(bad), -1).any(axis=1))[0]) + offset
        raise D5RLError(f"{path}: {name} has {int(bad.sum())} NaN or infinite values (first in row {row})", hint)
    big = np.abs(a) > MAX_ABS
    if big.any():
        row = int(np.flatnonzero(big.reshape(len(big), -1).any(axis=1))[0])
        raise D5RLError(
            f"{path}: {name} has values beyond ±{MAX_ABS:g} (first in row {row + offset}: "
            f"{a.reshape(len(a), -1)[row][big.reshape(len(big), -1)[row]][0]:g}), which no kitchen joint "
            "or action reaches",
            hint,
        )


def read_d4rl(path: Path, subtask_idx: dict[str, np.ndarray]) -> list[SourceEpisode]:
    """Episodes of a D4RL kitchen file; the file's claim is D4RL's own test (joint positions within 0.3 of
    the goal stored in the observation) for the subtasks its goal names."""
    hint = "this does not look like an intact D4RL kitchen file"
    with _h5py().File(path, "r") as f:
        for key in ("observations", "actions"):
            if key not in f:
                raise D5RLError(f"{path} has no {key!r} array", hint)
        obs = _read(f, "observations", path, str(path), "fiu", 2, hint, np.float64)
        actions = _read(f, "actions", path, str(path), "fiu", 2, hint, np.float32)
        n = len(obs)
        terminals = _read(f, "terminals", path, str(path), "biuf", 1, hint) if "terminals" in f else np.zeros(n, bool)
        timeouts = _read(f, "timeouts", path, str(path), "biuf", 1, hint) if "timeouts" in f else np.zeros(n, bool)
    if obs.ndim != 2 or obs.shape[1] != 60:
        raise D5RLError(f"{path}: observations have shape {obs.shape}, expected (N, 60)", hint)
    if n < 2:
        raise D5RLError(f"{path}: {n} observation rows; an episode needs at least 2", hint)
    for name, arr in (("actions", actions), ("terminals", terminals), ("timeouts", timeouts)):
        if len(arr) != n:
            raise D5RLError(f"{path}: {name} has {len(arr)} rows, observations have {n}", hint)
    if actions.ndim != 2 or actions.shape[1] != 9:
        raise D5RLError(f"{path}: actions have shape {actions.shape}, expected (N, 9)", hint)
    _finite(path, "observations", obs[:, :30], hint)
    _finite(path, "actions", actions, hint)
    episodes = []
    for a, b in _episode_bounds(terminals, timeouts, n):
        if b - a < 2:
            continue  # a single row has no transition
        qpos, goal = obs[a:b, :30], obs[a:b, 30:]
        # An episode of rows a..b-1: observation i, action i; the last row has no successor.
        claimed = {
            name: np.linalg.norm(qpos[1:, idx] - goal[1:, idx], axis=-1) < THRESHOLD
            for name, idx in subtask_idx.items()
            if np.any(goal[0, idx] != 0)
        }
        episodes.append(SourceEpisode(qpos, None, actions[a : b - 1], claimed, {"source_rows": [int(a), int(b)]}))
    if not episodes:
        raise D5RLError(f"{path}: no episode has 2 or more rows (every row ends one), so there is no transition", hint)
    return episodes


def read_minari(path: Path, subtask_idx: dict[str, np.ndarray]) -> list[SourceEpisode]:
    """Episodes of a Minari kitchen dataset (``main_data.hdf5``); the file's claim is gymnasium-robotics'
    test (``achieved_goal`` within 0.3 of ``desired_goal``) for its target subtasks."""
    hint = "this does not look like an intact Minari kitchen dataset (D4RL/kitchen/*-v2)"
    episodes = []
    with _h5py().File(path, "r") as f:
        names = sorted((k for k in f.keys() if k.startswith("episode_")), key=lambda k: int(k.split("_")[1]))
        if not names:
            raise D5RLError(f"{path} has no episode_* groups", hint)
        for name in names:
            g = f[name]
            where = f"{path}:{name}"
            for key in ("observations/observation", "actions"):
                if key not in g:
                    raise D5RLError(f"{where} has no {key!r}", hint)
            obs = _read(g, "observations/observation", path, where, "fiu", 2, hint, np.float64)
            actions = _read(g, "actions", path, where, "fiu", 2, hint, np.float32)
            if obs.ndim != 2 or obs.shape[1] != 59:
                raise D5RLError(f"{where}: observations/observation has shape {obs.shape}, expected (T+1, 59)", hint)
            if actions.shape != (len(obs) - 1, 9):
                raise D5RLError(
                    f"{where}: actions have shape {actions.shape}, expected ({len(obs) - 1}, 9) "
                    "(one fewer than observations)",
                    hint,
                )
            _finite(where, "observations/observation", obs, hint)
            _finite(where, "actions", actions, hint)
            qpos, qvel = obs[:, MINARI_QPOS], obs[:, MINARI_QVEL]
            claimed = {}
            for task in g["observations/achieved_goal"].keys() if "observations/achieved_goal" in g else []:
                if task not in subtask_idx:
                    continue
                achieved = _read(g, f"observations/achieved_goal/{task}", path, where, "fiu", 2, hint, np.float64)
                desired = _read(g, f"observations/desired_goal/{task}", path, where, "fiu", 2, hint, np.float64)
                if achieved.shape != (len(obs), len(subtask_idx[task])):
                    raise D5RLError(
                        f"{where}: achieved_goal/{task} has shape {achieved.shape}, expected "
                        f"({len(obs)}, {len(subtask_idx[task])})",
                        hint,
                    )
                qpos[:, subtask_idx[task]] = achieved  # noise-free, unlike observation
                claimed[task] = np.linalg.norm(achieved[1:] - desired[1:], axis=-1) < THRESHOLD
            if len(actions) >= 1:
                meta = {"source_episode": int(name.split("_")[1])}
                episodes.append(SourceEpisode(qpos, qvel, actions, claimed, meta))
    return episodes


def _source_id(kind: str, path: Path) -> str:
    if kind == "minari":
        meta = path.parent / "metadata.json"
        if meta.is_file():
            try:
                return str(json.loads(meta.read_text()).get("dataset_id") or path.parent.parent.name)
            except (OSError, ValueError):
                pass
        return path.parent.parent.name if path.parent.name == "data" else path.parent.name
    return path.name


# --- restoring states and checking the replay ------------------------------------------------------
def restore_states(model, qpos: np.ndarray, qvel: np.ndarray | None) -> np.ndarray:
    """Full integration states (rows of ``STATE_SPEC``) with the given joint positions and velocities."""
    import mujoco

    data = mujoco.MjData(model)
    out = np.empty((len(qpos), mujoco.mj_stateSize(model, STATE_SPEC)))
    for i, q in enumerate(qpos):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = q
        if qvel is not None:
            data.qvel[:] = qvel[i]
        mujoco.mj_getState(model, data, out[i], STATE_SPEC)
    return out


def replay_check(index: int, claimed: dict[str, np.ndarray], ours: np.ndarray) -> dict | None:
    """Where the file's per-step subtask claims and our scene's ``infos/completed`` disagree (None: nowhere)."""
    steps = {t: int((c != ours[:, SUBTASK_NAMES.index(t)]).sum()) for t, c in claimed.items()}
    steps = {t: n for t, n in steps.items() if n}
    if not steps:
        return None
    file_done = sorted(t for t, c in claimed.items() if c.any())
    our_done = sorted(t for t in claimed if ours[:, SUBTASK_NAMES.index(t)].any())
    return {"episode": index, "file_done": file_done, "scene_done": our_done, "steps_differ": steps}


ACTION_CHECK_STRIDE = 10  # every 10th transition: ~1/10 of an env step per transition on import


def action_errors(
    env, states: np.ndarray, qpos: np.ndarray, actions: np.ndarray, stride: int = ACTION_CHECK_STRIDE
) -> np.ndarray:
    """How far one step of our env, from a stored state with the stored action, lands from the next stored
    arm position (rad, the largest of the 7 arm joints), for every ``stride``-th transition: whether the
    file's actions move our robot as they moved the demonstrator's (what a policy learnt from them needs)."""
    out = []
    for t in range(0, len(actions), stride):
        env.set_state(states[t])
        env.step(actions[t])
        out.append(np.abs(env.data.qpos[:7] - qpos[t + 1, :7]).max())
    return np.asarray(out)


def completion_order(completed: np.ndarray) -> list[str]:
    """Subtasks in the order they first reach their goal in an episode (``infos/completed`` rows)."""
    first = {
        SUBTASK_NAMES[j]: int(np.argmax(completed[:, j])) for j in range(completed.shape[1]) if completed[:, j].any()
    }
    return sorted(first, key=lambda t: (first[t], SUBTASK_NAMES.index(t)))


# --- writing the d5rl dataset ----------------------------------------------------------------------
def import_human(
    source: str | Path,
    *,
    render: bool = True,
    cameras=("overview", "wrist"),
    size: int = 64,
    workers: int | None = None,
    progress: bool = True,
    out=print,
) -> Path:
    """Convert ``source`` into the ``kitchen-standard-human`` dataset; returns its directory."""
    renders(None, None, None, episodes=0, cameras=cameras, size=size, check=True)  # before reading the file
    kind, path = locate(source)
    model = km.build_model()
    idx = {name: s.qpos_indices(model) for name, s in SUBTASKS.items()}
    episodes = (read_minari if kind == "minari" else read_d4rl)(path, idx)
    if not episodes:
        raise D5RLError(f"{path} holds no episode with a transition", "check that the download finished")
    dspec = HUMAN_DATASET
    root = generation.dataset_root(dspec)
    ident = generation.identity(dspec)
    checker = CompletionChecker(model)
    mixed = [SUBTASK_NAMES.index(t) for t in MIXED]
    env = KitchenEnv(obs_mode="state")
    env.reset(seed=0)
    errors = []
    fmt.ensure_writable(root)
    with lock.writing(root, "import"):
        with lock.publishing(root):  # an import replaces whatever was imported before
            (root / fmt.MANIFEST).unlink(missing_ok=True)
            for sub in ("shards", "renders"):
                shutil.rmtree(root / sub, ignore_errors=True)
        (root / "shards").mkdir(parents=True)
        records, mismatches = [], []
        bar = progress_bar(total=len(episodes), unit="ep", desc=f"import {path.name}", disable=not progress)
        per = dspec.episodes_per_shard
        for s, first in enumerate(range(0, len(episodes), per)):
            parts: dict[str, list[np.ndarray]] = {}
            lengths, metas = [], []
            for i, ep in enumerate(episodes[first : first + per], start=first):
                t = len(ep.actions)
                done = checker.completed(ep.qpos[1:])
                problem = replay_check(i, ep.claimed, done)
                if problem is not None:
                    mismatches.append(problem)
                order = completion_order(done)
                states = restore_states(model, ep.qpos, ep.qvel)
                err = action_errors(env, states, ep.qpos, ep.actions)
                errors.append(err)
                arrays = {
                    "observations/proprio": ep.qpos[:, :9].astype(np.float32),
                    "states": states,
                    "actions": ep.actions,
                    "rewards": done[:, mixed].sum(axis=1).astype(np.float32),  # relabelled per task on load
                    "terminals": np.zeros(t, bool),
                    "timeouts": np.eye(1, t, t - 1, dtype=bool)[0],
                    "infos/completed": done,
                }
                for k, v in arrays.items():
                    parts.setdefault(k, []).append(v)
                lengths.append(t)
                metas.append(
                    {
                        **ep.meta,
                        "subtasks": order,
                        "solved": order,
                        "num_solved": len(order),
                        "action_error_median": round(float(np.median(err)), 5),
                    }
                )
                bar.update(1)
            writer = fmt.ShardWriter(root / "shards", s)
            for k, v in parts.items():
                writer.write(k, np.concatenate(v))
            aligns = {k: "step" if k in ("states", "observations/proprio") else "transition" for k in parts}
            records.append(
                writer.commit(
                    {
                        **ident,
                        "episodes": [first, first + len(lengths)],
                        "episode_lengths": lengths,
                        "episode_meta": metas,
                    },
                    aligns,
                )
            )
        bar.close()
        source_info = {
            "layout": kind,
            "id": _source_id(kind, path),
            "file": path.name,
            "sha256": fmt.sha256_file(path),
            "velocities": kind == "minari",
        }
        err = np.concatenate(errors)
        moves = np.concatenate([np.abs(np.diff(e.qpos[:, :7], axis=0)).max(axis=1) for e in episodes])
        actions_check = {
            "stride": ACTION_CHECK_STRIDE,
            "transitions": len(err),
            "median_rad": float(np.median(err)),
            "p90_rad": float(np.quantile(err, 0.9)),
            "median_step_rad": float(np.median(moves)),
        }
        check = {
            "episodes_checked": len(episodes),
            "episodes_mismatched": len(mismatches),
            "mismatches": mismatches,
            "actions": actions_check,
        }
        generation.write_manifest(
            root, dspec, ident, records, len(episodes), extra={"source": source_info, "replay_check": check}
        )
    out(
        f"imported {len(episodes)} episodes ({sum(len(e.actions) for e in episodes)} transitions) from "
        f"{source_info['id']} ({kind} layout) into {root}"
    )
    out(
        f"replay check: {len(episodes) - len(mismatches)} of {len(episodes)} episodes agree with the file "
        "on every step's subtasks"
    )
    for m in mismatches[:20]:
        out(
            f"  episode {m['episode']}: file says done {m['file_done']}, our scene {m['scene_done']}; "
            f"steps that differ: {m['steps_differ']}"
        )
    if len(mismatches) > 20:
        out(f"  ... {len(mismatches) - 20} more in {root / fmt.MANIFEST} (replay_check)")
    out(
        f"action check: one step of our env from a stored state with the stored action ends "
        f"{actions_check['median_rad']:.4f} rad (median; 90%: {actions_check['p90_rad']:.4f}) from the next stored "
        f"arm position (the arm moves {actions_check['median_step_rad']:.4f} rad a step, median), "
        f"over every {ACTION_CHECK_STRIDE}th transition"
    )
    if render:  # the camera tasks' frames, from the states (a regular derived cache)
        load_dataset(
            "kitchen-standard-mixed-human-v0",
            cameras=tuple(cameras),
            size=size,
            workers=workers,
            progress=progress,
            in_memory=False,
        )
    return root


def add_import_kitchen_human_parser(subparsers) -> None:
    q = subparsers.add_parser(
        "import-kitchen-human",
        help="import the paper's human kitchen demonstrations (Minari D4RL/kitchen/*-v2 or a D4RL .hdf5 file)",
        description="Replay the relay-policy-learning human demonstrations in our kitchen and write them as the "
        "dataset of the kitchen-standard-*-human-v0 tasks. " + KitchenHumanImport.how + ".",
    )
    q.add_argument(
        "source",
        help=f"Minari dataset id (e.g. {DEFAULT_SOURCE}, under $MINARI_DATASETS_PATH or "
        "~/.minari/datasets), its directory, or a D4RL kitchen_*-v0.hdf5 file",
    )
    q.add_argument("--size", type=int, default=64, help="image size of the rendered cache (64 or 128)")
    q.add_argument("--cameras", default="overview,wrist", help="comma-separated cameras")
    q.add_argument("--no-render", action="store_true", help="skip the camera frames (state tasks need none)")
    q.add_argument("--workers", type=int, default=None, help="render processes (default: all cores)")
    q.set_defaults(func=_cmd_import)


def _cmd_import(args: argparse.Namespace) -> int:
    import_human(
        args.source,
        render=not args.no_render,
        cameras=tuple(args.cameras.split(",")),
        size=args.size,
        workers=args.workers,
    )
    return 0
