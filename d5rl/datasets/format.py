"""On-disk dataset format (version 1).

A dataset is a directory of *shards*; each shard holds a contiguous range of
episodes as plain ``.npy`` arrays (memory-mappable, readable by any numpy) plus
a ``shard.json`` that records their checksums.  ``manifest.json`` is written
last and lists every shard: its presence means the dataset is complete::

    $D5RL_HOME/datasets/<dataset-name>/v<dataset-version>-seed<seed>/
    ├── manifest.json            format/dataset/generator versions, seed, sizes,
    │                            package versions, per-array sha256 of every shard
    ├── shards/
    │   ├── shard-00000/
    │   │   ├── shard.json       episode range, lengths, per-episode meta, checksums
    │   │   ├── observations.npy            (T+1 rows per episode: step-aligned)
    │   │   ├── states.npy                  (T+1, simulator state for replay/render)
    │   │   ├── actions.npy rewards.npy terminals.npy timeouts.npy   (T rows)
    │   │   └── infos.<name>.npy            ("/" in a key is "." in its file name)
    │   └── shard-00001/ ...
    └── renders/<cameras>-<H>x<W>/shard-00000/...   derived caches, same shard layout

Shards are written into a temporary sibling directory and renamed into place,
so a killed writer never leaves a half shard behind, and generation resumes at
the first missing shard.  Every byte is a function of (dataset version,
generator version, seed): no timestamps, hostnames or paths are stored.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from d5rl.errors import DatasetCorruptError, DatasetVersionError

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
SHARD_META = "shard.json"
_HASH_CHUNK = 1 << 22


def key_to_filename(key: str) -> str:
    if "." in key or key.startswith("/") or key.endswith("/") or "//" in key:
        raise ValueError(f"array key {key!r} may not contain '.' or empty path parts")
    return key.replace("/", ".") + ".npy"


def filename_to_key(name: str) -> str:
    return name[: -len(".npy")].replace(".", "/")


def shard_name(index: int) -> str:
    return f"shard-{index:05d}"


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def dump_json(obj: Any, path: Path) -> None:
    """Deterministic JSON (sorted keys), written atomically."""
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True, default=_json_default)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serializable")


def load_json(path: Path, what: str) -> dict:
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        raise
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DatasetCorruptError(f"{what} {path} is not valid JSON ({e})", _regen_hint(path)) from e


def _regen_hint(path: Path) -> str:
    return f"delete {path.parent} (or run `d5rl generate TASK --force`) and regenerate"


class ShardWriter:
    """Writes one shard into a temporary directory, then renames it into place.

    Arrays are either passed whole (:meth:`write`) or streamed into a
    memory-mapped file (:meth:`open`) for data larger than RAM.
    """

    def __init__(self, root: Path, index: int):
        self.root = Path(root)
        self.index = index
        self.final = self.root / shard_name(index)
        self.tmp = self.root / f".{shard_name(index)}.tmp-{os.getpid()}"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        self._keys: list[str] = []

    def write(self, key: str, array: np.ndarray) -> None:
        np.save(self.tmp / key_to_filename(key), np.ascontiguousarray(array), allow_pickle=False)
        self._keys.append(key)

    def open(self, key: str, shape: tuple[int, ...], dtype) -> np.memmap:
        self._keys.append(key)
        return np.lib.format.open_memmap(self.tmp / key_to_filename(key), mode="w+", dtype=dtype, shape=shape)

    def commit(self, meta: dict, aligns: dict[str, str]) -> dict:
        """Checksum every array, write ``shard.json``, rename into place; return the shard record."""
        arrays = {}
        for key in sorted(set(self._keys)):
            path = self.tmp / key_to_filename(key)
            arr = np.load(path, mmap_mode="r")
            arrays[key] = {
                "file": path.name,
                "sha256": sha256_file(path),
                "shape": list(arr.shape),
                "dtype": arr.dtype.str,
                "align": aligns[key],
            }
            del arr
        record = {**meta, "format_version": FORMAT_VERSION, "name": self.final.name, "arrays": arrays}
        dump_json(record, self.tmp / SHARD_META)
        for p in self.tmp.iterdir():  # make the data durable before the rename publishes it
            with open(p, "rb") as f:
                os.fsync(f.fileno())
        if self.final.exists():
            shutil.rmtree(self.final)
        os.rename(self.tmp, self.final)
        return record

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


def clean_temporaries(root: Path) -> int:
    """Remove leftovers of killed writers (``.shard-*.tmp-*``) and of killed Ray runs'
    shared-directory checks (``.ray-check-*``); return how many."""
    n = 0
    if root.exists():
        for p in root.glob(".shard-*.tmp-*"):
            shutil.rmtree(p, ignore_errors=True)
            n += 1
        for p in root.glob(".ray-check-*"):
            p.unlink(missing_ok=True)
            n += 1
    return n


def read_shard_record(shard_dir: Path) -> dict:
    path = shard_dir / SHARD_META
    record = load_json(path, "shard record")
    if record.get("format_version") != FORMAT_VERSION:
        raise DatasetVersionError(
            f"{shard_dir} has format version {record.get('format_version')}, this d5rl reads {FORMAT_VERSION}",
            f"regenerate it: `d5rl generate TASK --force` (or delete {shard_dir.parent.parent})",
        )
    return record


def open_array(shard_dir: Path, info: dict, mmap: bool = True) -> np.ndarray:
    path = shard_dir / info["file"]
    try:
        arr = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except FileNotFoundError:
        raise DatasetCorruptError(f"missing array file {path}", _regen_hint(shard_dir)) from None
    except ValueError as e:
        raise DatasetCorruptError(f"unreadable array file {path}: {e}", _regen_hint(shard_dir)) from e
    if list(arr.shape) != info["shape"] or arr.dtype.str != info["dtype"]:
        raise DatasetCorruptError(
            f"{path} has shape {arr.shape} {arr.dtype.str}, its record says {tuple(info['shape'])} {info['dtype']}",
            _regen_hint(shard_dir),
        )
    return arr


def verify_shard(shard_dir: Path, expected: dict | None = None) -> list[str]:
    """Problems found in one shard (empty list = intact): missing files, wrong checksums."""
    problems = []
    try:
        record = read_shard_record(shard_dir)
    except FileNotFoundError:
        return [f"{shard_dir}: missing {SHARD_META}"]
    except (DatasetCorruptError, DatasetVersionError) as e:
        return [f"{shard_dir}: {e.message}"]
    if expected is not None and expected.get("arrays") != record.get("arrays"):
        problems.append(f"{shard_dir}: {SHARD_META} disagrees with the manifest")
    for key, info in record["arrays"].items():
        path = shard_dir / info["file"]
        if not path.exists():
            problems.append(f"{path}: missing")
            continue
        digest = sha256_file(path)
        if digest != info["sha256"]:
            problems.append(f"{path}: checksum mismatch (expected {info['sha256'][:12]}…, got {digest[:12]}…)")
    return problems


def iter_shard_dirs(root: Path) -> Iterable[Path]:
    return sorted(p for p in Path(root).glob("shard-*") if p.is_dir())


def package_versions() -> dict[str, str]:
    import gymnasium
    import mujoco

    import d5rl

    return {"d5rl": d5rl.__version__, "mujoco": mujoco.__version__, "numpy": np.__version__,
            "gymnasium": gymnasium.__version__}
