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
    └── renders/<cameras>-<H>x<W>/shard-00000/...   derived caches, same shard layout; camera
                                                    frames as compressed chunks (``.zch``, see
                                                    :mod:`d5rl.datasets.chunks`)

Shards are written into a temporary sibling directory and renamed into place,
so a killed writer never leaves a half shard behind, and generation resumes at
the first missing shard.  Every byte is a function of (dataset version,
generator version, seed): no timestamps, hostnames or paths are stored.

Integrity: every array's sha256 is in its ``shard.json`` and the manifest.  Loading
re-hashes a shard only when its files changed since they were last verified:
``.verified.json`` in the shard remembers each file's size, mtime, ctime and inode
at the last successful check (the writer stores it when it commits, so fresh data
loads without a re-hash).  ``d5rl verify`` re-hashes everything regardless.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
import socket
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from d5rl.datasets import chunks, lock
from d5rl.errors import D5RLError, DatasetCorruptError, DatasetVersionError, is_int
from d5rl.files import dump_json, json_type_error, owner_tag, read_json, write_atomic
from d5rl.version import __version__

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
SHARD_META = "shard.json"
STAMP = ".verified.json"
_HASH_CHUNK = 1 << 22


def key_to_filename(key: str, suffix: str = ".npy") -> str:
    if "." in key or key.startswith("/") or key.endswith("/") or "//" in key:
        raise ValueError(f"array key {key!r} may not contain '.' or empty path parts")
    return key.replace("/", ".") + suffix


def filename_to_key(name: str) -> str:
    return name.rsplit(".", 1)[0].replace(".", "/")


def shard_name(index: int) -> str:
    return f"shard-{index:05d}"


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def load_json(path: Path, what: str) -> Any:
    """A dataset's JSON file, bounded (:func:`d5rl.files.read_json`); damage is a :class:`DatasetCorruptError`
    whose hint is the command that repairs it."""
    return read_json(path, what, error=DatasetCorruptError, hint=_regen_hint(path))


def _regen_hint(path: Path) -> str:
    return "run `d5rl generate TASK`: it regenerates missing or damaged shards and keeps the intact ones"


_FILE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")  # what key_to_filename makes: no path, no dot-file
_SHA256 = re.compile(r"[0-9a-f]{64}")


def _array_problem(info: Any, stored: bool) -> tuple[str, Any, str] | None:
    """(field, value, expected) for the first wrong-typed field of one array's description, or None;
    ``stored``: a shard's array (with its file and checksum), not the manifest's summary."""
    if not isinstance(info, dict):
        return "", info, "an object"
    shape = info.get("shape")
    if not isinstance(shape, list) or not all(is_int(n, lo=0) for n in shape):
        return ".shape", shape, "a list of non-negative integers"
    try:
        dtype = np.dtype(info.get("dtype"))
        ok = isinstance(info.get("dtype"), str) and not dtype.hasobject
    except (TypeError, ValueError):
        ok = False
    if not ok:
        return ".dtype", info.get("dtype"), "a numpy dtype string such as '<f4'"
    if info.get("align") not in ("step", "transition"):
        return ".align", info.get("align"), "'step' or 'transition'"
    if stored:
        if not isinstance(info.get("file"), str) or not _FILE_NAME.fullmatch(info["file"]):
            return ".file", info.get("file"), "a file name inside the shard"
        if not isinstance(info.get("sha256"), str) or not _SHA256.fullmatch(info["sha256"]):
            return ".sha256", info.get("sha256"), "64 hex digits"
        if not isinstance(info.get("encoding", ""), str):
            return ".encoding", info.get("encoding"), "a string"
    return None


def _arrays_problem(arrays: Any, stored: bool, where: str) -> tuple[str, Any, str] | None:
    if not isinstance(arrays, dict) or not arrays:
        return where, arrays, "an object of arrays"
    for key, info in arrays.items():
        problem = _array_problem(info, stored)
        if problem is not None:
            return f"{where}[{key!r}]{problem[0]}", problem[1], problem[2]
    return None


def _range_problem(episodes: Any, where: str) -> tuple[str, Any, str] | None:
    if not (
        isinstance(episodes, list)
        and len(episodes) == 2
        and all(is_int(n, lo=0) for n in episodes)
        and episodes[0] < episodes[1]
    ):
        return where, episodes, "[first, end) episode numbers"
    return None


def _manifest_problem(m: dict) -> tuple[str, Any, str] | None:
    for key in ("num_episodes", "num_transitions", "episodes_per_shard"):
        if not is_int(m.get(key), lo=0):
            return key, m.get(key), "a non-negative integer"
    problem = _arrays_problem(m.get("arrays"), False, "arrays")
    if problem is not None:
        return problem
    shards = m.get("shards")
    if not isinstance(shards, list) or not shards:
        return "shards", shards, "a list of shards"
    for i, e in enumerate(shards):
        if not isinstance(e, dict) or not isinstance(e.get("name"), str) or not re.fullmatch(r"shard-\d+", e["name"]):
            return f"shards[{i}]", e, "an object with the shard's name"
        problem = _range_problem(e.get("episodes"), f"shards[{i}].episodes") or _arrays_problem(
            e.get("arrays"), True, f"shards[{i}].arrays"
        )
        if problem is not None:
            return problem
    if shards[-1]["episodes"][1] < m["num_episodes"]:
        return "num_episodes", m["num_episodes"], f"at most its last shard's end, {shards[-1]['episodes'][1]}"
    return None


def _record_problem(r: dict) -> tuple[str, Any, str] | None:
    problem = _range_problem(r.get("episodes"), "episodes")
    if problem is not None:
        return problem
    n = r["episodes"][1] - r["episodes"][0]
    lengths = r.get("episode_lengths")
    if not isinstance(lengths, list) or len(lengths) != n or not all(is_int(x, lo=1) for x in lengths):
        return "episode_lengths", lengths, f"{n} positive integers"
    metas = r.get("episode_meta")
    if not isinstance(metas, list) or len(metas) != n or not all(isinstance(x, dict) for x in metas):
        return "episode_meta", metas, f"{n} objects"
    return _arrays_problem(r.get("arrays"), True, "arrays")


def read_manifest(path: Path) -> dict:
    """``manifest.json``, its fields type-checked; :class:`DatasetVersionError` for a format this d5rl does not
    read, :class:`DatasetCorruptError` (repaired by ``d5rl generate``) for anything else wrong."""
    manifest = load_json(path, "manifest")
    if not isinstance(manifest, dict):
        raise json_type_error(
            "manifest", path, "the file", manifest, "a JSON object", DatasetCorruptError, _regen_hint(path)
        )
    found = manifest.get("format_version")
    if is_int(found) and found != FORMAT_VERSION:
        raise DatasetVersionError(
            f"{path} has format version {found!r}, this d5rl reads version {FORMAT_VERSION}",
            "use the d5rl version that wrote it, or regenerate: `d5rl generate TASK --force`",
        )
    problem = ("format_version", found, str(FORMAT_VERSION)) if found != FORMAT_VERSION else _manifest_problem(manifest)
    if problem is not None:
        raise json_type_error("manifest", path, *problem, DatasetCorruptError, _regen_hint(path))
    return manifest


# --- temporaries: named after their owner, removed only when the owner is gone -----------------------------
def _owner_alive(name: str) -> bool:
    """Whether the process that made ``.<x>.tmp-<host>-<pid>-<random>`` may still be writing it."""
    tag = name.rsplit(".tmp-", 1)[-1] if ".tmp-" in name else name.rsplit(".old-", 1)[-1]
    parts = tag.rsplit("-", 2)
    if len(parts) != 3 or not parts[1].isdigit():
        return False
    host, pid = parts[0], int(parts[1])
    if host != socket.gethostname():
        return True  # another node's worker (Ray): cannot tell, leave it
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def disk_full_error(path: Path, exc: OSError, hint: str | None = None) -> D5RLError | None:
    """A one-line error for a write that failed because the disk is full (numpy's short writes
    carry no errno, so the free space decides); None if the disk is not the cause.  ``hint``: what to
    do (default: for data under ``D5RL_HOME``)."""
    code = getattr(exc, "errno", None)
    if code not in (None, errno.ENOSPC):
        return None  # the OS named another cause (no such directory, permission denied, ...)
    try:
        free = shutil.disk_usage(path if path.exists() else path.parent).free
    except OSError:
        free = None
    if code == errno.ENOSPC or (free is not None and free < 64 << 20):
        where = f" ({free / 2**20:.0f} MiB free)" if free is not None else ""
        return D5RLError(
            f"the disk holding {path} is full{where}",
            hint
            or "free some space or point D5RL_HOME at a bigger disk, then run the same command "
            "again (finished shards are kept)",
        )
    return None


def ensure_writable(path: Path) -> None:
    """Create ``path`` and check that files can be written there, before any work starts."""
    probe = Path(path) / f".write-test-{owner_tag()}"
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
        probe.touch()
        probe.unlink()
    except OSError as e:
        raise D5RLError(
            f"cannot write to {path} ({e.strerror or e})",
            "set D5RL_HOME to a writable directory (datasets go to $D5RL_HOME/datasets)",
        ) from None


class ShardWriter:
    """Writes one shard into a temporary directory, then renames it into place.

    Arrays are either passed whole (:meth:`write`) or streamed into a
    memory-mapped file (:meth:`open`) for data larger than RAM.
    """

    def __init__(self, root: Path, index: int, lock_root: Path | None = None):
        self.root = Path(root)
        self.lock_root = Path(lock_root) if lock_root is not None else self.root.parent  # <dataset>/shards -> <dataset>
        self.index = index
        self.final = self.root / shard_name(index)
        self.tmp = self.root / f".{shard_name(index)}.tmp-{owner_tag()}"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        self._keys: list[str] = []
        self._chunked: dict[str, chunks.ChunkWriter] = {}

    def write(self, key: str, array: np.ndarray) -> None:
        np.save(self.tmp / key_to_filename(key), np.ascontiguousarray(array), allow_pickle=False)
        self._keys.append(key)

    def open(self, key: str, shape: tuple[int, ...], dtype) -> np.memmap:
        self._keys.append(key)
        return np.lib.format.open_memmap(self.tmp / key_to_filename(key), mode="w+", dtype=dtype, shape=shape)

    def open_chunked(self, key: str, row_shape: tuple[int, ...], dtype) -> chunks.ChunkWriter:
        """A losslessly compressed array (:mod:`d5rl.datasets.chunks`) streamed episode by episode
        with ``.append(rows)``; closed by :meth:`commit`."""
        w = chunks.ChunkWriter(self.tmp / key_to_filename(key, chunks.SUFFIX), row_shape, dtype)
        self._chunked[key] = w
        self._keys.append(key)
        return w

    def commit(self, meta: dict, aligns: dict[str, str]) -> dict:
        """Checksum every array, write ``shard.json``, rename into place; return the shard record."""
        arrays = {}
        for key in sorted(set(self._keys)):
            if key in self._chunked:
                w = self._chunked[key]
                shape, dtype, path = w.close(), w.dtype, w.path
            else:
                path = self.tmp / key_to_filename(key)
                arr = np.load(path, mmap_mode="r")
                shape, dtype = arr.shape, arr.dtype
                del arr
            arrays[key] = {
                "file": path.name,
                "sha256": sha256_file(path),
                "shape": list(shape),
                "dtype": dtype.str,
                "align": aligns[key],
            }
            if key in self._chunked:
                arrays[key]["encoding"] = chunks.ENCODING
        record = {**meta, "format_version": FORMAT_VERSION, "name": self.final.name, "arrays": arrays}
        dump_json(record, self.tmp / SHARD_META)
        for p in self.tmp.iterdir():  # make the data durable before the rename publishes it
            with open(p, "rb") as f:
                os.fsync(f.fileno())
        write_stamp(self.tmp, record)  # just hashed: file stats survive the rename below
        old = None
        with lock.publishing(self.lock_root):  # no reader is opening shards meanwhile
            if self.final.exists():
                old = self.root / f".{self.final.name}.old-{owner_tag()}"
                os.rename(self.final, old)
            os.rename(self.tmp, self.final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return record

    @property
    def keys(self) -> list[str]:
        return sorted(set(self._keys))

    def abort(self) -> None:
        for w in self._chunked.values():
            w.abort()
        shutil.rmtree(self.tmp, ignore_errors=True)


def clean_temporaries(root: Path) -> int:
    """Remove leftovers of dead writers (``.shard-*.tmp-*``, ``.shard-*.old-*``; a live owner's are
    kept) and of killed Ray runs' shared-directory checks (``.ray-check-*``); return how many.
    Callers hold the dataset's write lock, so no other run is using them."""
    n = 0
    if root.exists():
        for p in [*root.glob(".shard-*.tmp-*"), *root.glob(".shard-*.old-*")]:
            if not _owner_alive(p.name):
                shutil.rmtree(p, ignore_errors=True)
                n += 1
        for p in root.glob(".ray-check-*"):
            p.unlink(missing_ok=True)
            n += 1
    return n


def read_shard_record(shard_dir: Path) -> dict:
    """A shard's ``shard.json``, its fields type-checked (:class:`DatasetCorruptError` when wrong)."""
    path = shard_dir / SHARD_META
    record = load_json(path, "shard record")
    if not isinstance(record, dict):
        raise json_type_error(
            "shard record", path, "the file", record, "a JSON object", DatasetCorruptError, _regen_hint(path)
        )
    if is_int(record.get("format_version")) and record["format_version"] != FORMAT_VERSION:
        raise DatasetVersionError(
            f"{shard_dir} has format version {record.get('format_version')}, this d5rl reads {FORMAT_VERSION}",
            f"regenerate it: `d5rl generate TASK --force` (or delete {shard_dir.parent.parent})",
        )
    problem = (
        ("format_version", record.get("format_version"), str(FORMAT_VERSION))
        if record.get("format_version") != FORMAT_VERSION
        else _record_problem(record)
    )
    if problem is not None:
        raise json_type_error("shard record", path, *problem, DatasetCorruptError, _regen_hint(path))
    return record


def open_array(shard_dir: Path, info: dict, mmap: bool = True) -> np.ndarray | chunks.CompressedArray:
    """One array of a shard: memory-mapped ``.npy`` (read into RAM if not ``mmap``) or, for an
    ``encoding`` of :mod:`d5rl.datasets.chunks`, a :class:`~d5rl.datasets.chunks.CompressedArray`
    that decodes the rows asked for."""
    path = shard_dir / info["file"]
    encoding = info.get("encoding")
    if encoding not in (None, chunks.ENCODING):
        raise DatasetVersionError(
            f"{path} is stored as {encoding!r}, which this d5rl does not read",
            "use the d5rl version that wrote it, or regenerate: `d5rl generate TASK --force`",
        )
    try:
        if encoding is None:
            arr = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
        else:
            arr = chunks.CompressedArray(path)
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


def first_rows(arr, rows: int):
    """The first ``rows`` rows of an opened array, without reading or decoding them."""
    return arr.head(rows) if isinstance(arr, chunks.CompressedArray) else arr[:rows]


def verify_shard(shard_dir: Path, expected: dict | None = None) -> list[str]:
    """Problems found in one shard by re-hashing every array (empty list = intact)."""
    try:
        record = read_shard_record(shard_dir)
    except FileNotFoundError:
        return [f"{shard_dir}: missing {SHARD_META}"]
    except (DatasetCorruptError, DatasetVersionError) as e:
        return [f"{shard_dir}: {e.message}"]
    if expected is not None and expected.get("arrays") != record.get("arrays"):
        return [f"{shard_dir}: {SHARD_META} disagrees with the manifest"]
    return _hash_check(shard_dir, record)


def _hash_check(shard_dir: Path, record: dict) -> list[str]:
    problems = []
    for info in record["arrays"].values():
        path = shard_dir / info["file"]
        if not path.exists():
            problems.append(f"{path}: missing")
            continue
        digest = sha256_file(path)
        if digest != info["sha256"]:
            problems.append(f"{path}: checksum mismatch (expected {info['sha256'][:12]}…, got {digest[:12]}…)")
    if not problems:
        write_stamp(shard_dir, record)
    return problems


# --- verify once, remember by file stats ------------------------------------------------------------------
_STAMP_MEMO: dict[str, dict] = {}  # for read-only datasets, where the stamp file cannot be written


def _file_stats(shard_dir: Path, record: dict) -> dict[str, list[int]]:
    out = {}
    for name in sorted([info["file"] for info in record["arrays"].values()] + [SHARD_META]):
        st = os.stat(shard_dir / name)
        out[name] = [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
    return out


def write_stamp(shard_dir: Path, record: dict) -> None:
    """Remember that ``shard_dir``'s files, as they are now, match ``record``'s checksums."""
    try:
        stats = _file_stats(shard_dir, record)
    except OSError:
        return
    _STAMP_MEMO[str(shard_dir.resolve())] = stats
    try:
        write_atomic(shard_dir / STAMP, json.dumps(stats, sort_keys=True))
    except OSError:
        pass  # read-only dataset: the in-process memo still spares re-hashing within this process


def check_shard(shard_dir: Path, record: dict) -> list[str]:
    """Problems of one shard against ``record`` (empty = intact), re-hashing only files whose
    size, mtime, ctime or inode changed since they were last verified."""
    try:
        stats = _file_stats(shard_dir, record)
    except FileNotFoundError as e:
        return [f"{e.filename}: missing"]
    known = _STAMP_MEMO.get(str(shard_dir.resolve()))
    if known != stats:
        try:
            known = json.loads((shard_dir / STAMP).read_text())
        except (OSError, ValueError):
            known = None
    if known == stats:
        return []
    return _hash_check(shard_dir, record)


def iter_shard_dirs(root: Path) -> Iterable[Path]:
    return sorted(p for p in Path(root).glob("shard-*") if p.is_dir())


def package_versions() -> dict[str, str]:
    import gymnasium
    import mujoco

    return {
        "d5rl": __version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
    }
