"""Training checkpoints that cannot run code: msgpack + JSON + ``.npz``, checksummed, atomic.

::

    run_dir/checkpoint/            the latest
    │   ├── manifest.json          format version; sha256 and size of every other file (written last)
    │   ├── agent.msgpack          the agent (``flax.serialization``: numbers and arrays only)
    │   ├── state.json             step counters, the sampler's RNG state, running metric sums
    │   └── buffer.npz             the online replay buffer (numeric arrays, read with allow_pickle=False)
    run_dir/checkpoint.prev/       the one before it

A checkpoint is written into a temporary directory, fsynced, and renamed into place; the
previous one is kept.  Loading checks every file against the manifest: a damaged latest
checkpoint falls back to the previous one with a one-line warning, and if none is usable the
error names the file.  Nothing here unpickles: a ``state.pkl`` of older d5rl versions is
refused, never opened.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from d5rl.errors import D5RLError, is_int
from d5rl.files import json_type_error, read_bytes, read_json, read_npz
from d5rl.training.rundir import CHECKPOINT_TMP_PREFIX, RunDir

FORMAT_VERSION = 1
MANIFEST = "manifest.json"


class CheckpointError(D5RLError):
    """A checkpoint that is damaged, truncated, of an unknown format, or does not fit the run."""


@dataclasses.dataclass
class Checkpoint:
    agent: bytes  # agent.to_bytes()
    state: dict[str, Any]  # JSON-serializable loop state
    buffer: dict[str, np.ndarray] | None = None  # ReplayBuffer.state_dict()
    path: Path | None = None  # where it was read from


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def save_checkpoint(run_dir: str | Path, ckpt: Checkpoint) -> Path:
    """Write ``run_dir/checkpoint`` atomically, keeping the one before as ``checkpoint.prev``."""
    run_dir = Path(run_dir)
    for stale in run_dir.glob(f"{CHECKPOINT_TMP_PREFIX}*"):  # a killed writer's leftovers
        shutil.rmtree(stale, ignore_errors=True)
    tmp = RunDir(run_dir).checkpoint_tmp(os.getpid())
    tmp.mkdir(parents=True)
    files = {
        "agent.msgpack": bytes(ckpt.agent),
        "state.json": (json.dumps(ckpt.state, sort_keys=True, allow_nan=False) + "\n").encode(),
    }
    if ckpt.buffer is not None:
        bio = io.BytesIO()
        np.savez(bio, **ckpt.buffer)
        files["buffer.npz"] = bio.getvalue()
    manifest = {
        "format_version": FORMAT_VERSION,
        "files": {name: {"sha256": _sha256(data), "bytes": len(data)} for name, data in files.items()},
    }
    files[MANIFEST] = (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()
    for name, data in files.items():
        with open(tmp / name, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    _fsync_dir(tmp)
    latest, previous = RunDir(run_dir).checkpoint, RunDir(run_dir).previous_checkpoint
    if latest.exists():
        shutil.rmtree(previous, ignore_errors=True)
        latest.rename(previous)
    tmp.rename(latest)
    _fsync_dir(run_dir)
    return latest


MANIFEST_MAX_BYTES = 1 << 20  # a checkpoint manifest lists four files


def _manifest_files(manifest, where: Path) -> dict[str, dict]:
    """The ``files`` of a checkpoint manifest, each name a plain file and each entry ``{sha256, bytes}``."""
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise json_type_error("checkpoint manifest", where, "files", files, "an object of file names", CheckpointError)
    for name, info in files.items():
        if "/" in name or name.startswith("."):
            raise CheckpointError(f"{where} names an unexpected file {name!r}")
        if not (isinstance(info, dict) and is_int(info.get("bytes"), lo=0) and isinstance(info.get("sha256"), str)):
            raise json_type_error(
                "checkpoint manifest",
                where,
                f"files[{name!r}]",
                info,
                "an object with the file's bytes and sha256",
                CheckpointError,
            )
    return files


def check_state(state, where: Path) -> dict:
    """A training run's checkpoint ``state.json`` with the types ``RunState.from_json`` needs (one line if not)."""

    def bad(field, value, expected):
        return json_type_error("checkpoint state", where, field, value, expected, CheckpointError)

    if not isinstance(state, dict):
        raise bad("the file", state, "a JSON object")
    for key in ("step", "online_done", "episode", "metric_count"):
        if not is_int(state.get(key), lo=0):
            raise bad(key, state.get(key), "a non-negative integer")
    if not isinstance(state.get("online_started"), bool):
        raise bad("online_started", state.get("online_started"), "true or false")
    sums = state.get("metric_sums")
    if not isinstance(sums, dict) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in sums.values()
    ):
        raise bad("metric_sums", sums, "an object of numbers")
    elapsed = state.get("elapsed_s", 0.0)
    if isinstance(elapsed, bool) or not isinstance(elapsed, (int, float)) or not elapsed >= 0:
        raise bad("elapsed_s", elapsed, "a non-negative number of seconds")
    try:
        np.random.default_rng().bit_generator.state = state.get("rng")
    except (TypeError, ValueError, KeyError):
        raise bad("rng", state.get("rng"), "the state of numpy's PCG64 generator") from None
    return state


def read_checkpoint(path: str | Path) -> Checkpoint:
    """One checkpoint directory, every file checked against its manifest; :class:`CheckpointError` if not intact.

    Every file is a regular file no larger than its manifest says, checked before it is read (a
    symlink to ``/dev/zero`` or a FIFO is refused, not read until memory or patience runs out)."""
    path = Path(path)
    if (path / "state.pkl").exists() and not (path / MANIFEST).exists():
        raise CheckpointError(
            f"{path} is a pickle checkpoint of an older d5rl, which this version never opens (unpickling can run code)",
            "train again from scratch in a new --run-dir",
        )
    try:
        manifest = read_json(
            path / MANIFEST, "checkpoint manifest", max_bytes=MANIFEST_MAX_BYTES, error=CheckpointError
        )
    except FileNotFoundError:
        raise CheckpointError(f"{path / MANIFEST} is missing (an incomplete checkpoint)") from None
    if not isinstance(manifest, dict) or manifest.get("format_version") != FORMAT_VERSION:
        version = manifest.get("format_version") if isinstance(manifest, dict) else None
        raise CheckpointError(
            f"{path} has checkpoint format {version!r}; this d5rl reads {FORMAT_VERSION}",
            "use the d5rl version that wrote it, or train again in a new --run-dir",
        )
    data: dict[str, bytes] = {}
    for name, info in _manifest_files(manifest, path / MANIFEST).items():
        try:
            blob = read_bytes(
                path / name,
                info["bytes"],
                "checkpoint file",
                error=CheckpointError,
                hint=f"delete {path} to fall back to the previous checkpoint",
            )
        except FileNotFoundError:
            raise CheckpointError(f"{path / name} is missing") from None
        if len(blob) != info["bytes"] or _sha256(blob) != info["sha256"]:
            raise CheckpointError(f"{path / name} is damaged (size or sha256 differs from its manifest)")
        data[name] = blob
    if "agent.msgpack" not in data or "state.json" not in data:
        raise CheckpointError(f"{path / MANIFEST} lists no agent.msgpack or state.json")
    try:
        state = json.loads(data["state.json"])
    except ValueError:
        raise CheckpointError(f"{path / 'state.json'} is not valid JSON") from None
    except RecursionError:
        raise CheckpointError(f"{path / 'state.json'} nests too deeply to be a file d5rl wrote") from None
    buffer = None
    if "buffer.npz" in data:
        buffer = read_npz(data["buffer.npz"], path / "buffer.npz", error=CheckpointError)
    return Checkpoint(data["agent.msgpack"], state, buffer, path)


def load_checkpoint(run_dir: str | Path, warn=None) -> Checkpoint | None:
    """The newest intact checkpoint of a run, or None if it has none.

    A damaged latest checkpoint falls back to the previous one with a one-line warning (to
    ``warn``, default stderr); if every checkpoint present is damaged, :class:`CheckpointError`
    names the first.
    """
    run_dir = Path(run_dir)
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    first_error: CheckpointError | None = None
    for path in (RunDir(run_dir).checkpoint, RunDir(run_dir).previous_checkpoint):
        if not path.exists():
            continue
        try:
            ckpt = read_checkpoint(path)
        except CheckpointError as e:
            first_error = first_error or e
            continue
        if first_error is not None:
            warn(f"{first_error.message}; using the previous checkpoint {path}")
        return ckpt
    if first_error is not None:
        raise CheckpointError(
            first_error.message,
            first_error.hint or f"delete {run_dir}/checkpoint* to start over, or pick another --run-dir",
        )
    return None


def restore_agent(agent, ckpt: Checkpoint):
    """``agent.from_bytes`` with a one-line error when the saved agent does not fit this one."""
    import jax  # JAX: only restoring an agent needs it; reading and writing checkpoints does not

    hint = "the run's config.json, data and checkpoint disagree; start a new --run-dir"
    try:
        restored = agent.from_bytes(ckpt.agent)
    except Exception as e:  # noqa: BLE001 - msgpack/flax raise many types for a mismatched tree
        raise CheckpointError(
            f"{ckpt.path / 'agent.msgpack'} does not fit this agent ({e.__class__.__name__}: "
            f"{str(e).splitlines()[0][:160] if str(e) else ''})",
            hint,
        ) from None
    # flax restores arrays of any shape into the tree: a checkpoint of another observation size
    # would only fail deep inside the first update
    for (path, new), old in zip(jax.tree_util.tree_leaves_with_path(restored), jax.tree_util.tree_leaves(agent)):
        if np.shape(new) != np.shape(old):
            raise CheckpointError(
                f"{ckpt.path / 'agent.msgpack'} does not fit this agent: "
                f"{jax.tree_util.keystr(path)} has shape {np.shape(new)}, this agent's "
                f"{np.shape(old)} (another observation or action size?)",
                hint,
            )
    return restored
