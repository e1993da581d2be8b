"""Writing files so that a reader or a crash never sees half of one: write a uniquely named temporary
file next to the target, fsync it, rename it over the target (atomic on POSIX).

Reading files with bounds: :func:`open_regular` opens only a regular file (a FIFO would block a read
forever, ``/dev/zero`` never ends; a symlink to either is refused the same way) no larger than the
caller allows, checked before a byte is read; :func:`read_json` reads JSON through it and turns
every way JSON can be wrong, deep nesting included, into one-line errors.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import stat
from pathlib import Path
from typing import Any

import numpy as np

from d5rl.errors import D5RLError

JSON_MAX_BYTES = 64 << 20  # the largest JSON file d5rl writes (a big dataset's manifest) is a few MB


def owner_tag() -> str:
    """``<host>-<pid>-<random>``: unique per writer, and says which process to ask whether it is alive."""
    return f"{socket.gethostname()}-{os.getpid()}-{os.urandom(4).hex()}"


def write_atomic(path: str | Path, data: str | bytes) -> None:
    """Replace ``path`` with ``data`` in one step (durable before it becomes visible)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{owner_tag()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def dump_json(obj: Any, path: str | Path, indent: int = 1) -> None:
    """Deterministic JSON (sorted keys; numpy scalars and arrays as plain values), written atomically."""
    write_atomic(path, json.dumps(obj, indent=indent, sort_keys=True, default=json_default) + "\n")


def json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serializable")


@contextlib.contextmanager
def try_lock(path: str | Path):
    """An exclusive, non-blocking ``flock`` on ``path`` (created; released by the kernel when this process
    dies, so a killed run never leaves a stale lock).  Yields True while held, False if another process holds
    it; the holder's pid is in the file (:func:`lock_holder`)."""
    import fcntl

    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            yield True
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def lock_holder(path: str | Path) -> int | None:
    """The pid written into a :func:`try_lock` file by its last holder (None if unknown)."""
    with contextlib.suppress(OSError, ValueError, IndexError, D5RLError):
        return int(read_bytes(path, 64, "lock file").split()[0])
    return None


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a directory"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def open_regular(
    path: str | Path,
    max_bytes: int | None,
    what: str = "file",
    *,
    error: type[D5RLError] = D5RLError,
    hint: str | None = None,
):
    """``path`` opened for binary reading, after checking (on the opened file, so a symlink is judged
    by its target) that it is a regular file of at most ``max_bytes`` bytes (None: any size).

    The open itself is non-blocking: opening a FIFO with no writer would wait forever.
    ``FileNotFoundError`` passes through; anything else is one ``error`` line."""
    path = Path(path)
    hint = hint or f"replace {path} with the file d5rl wrote there, or delete it"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise
    except OSError as e:
        raise error(f"cannot open {what} {path}: {e.strerror}", hint) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{what} {path} is {_kind(st.st_mode)}, not a regular file", hint)
        if max_bytes is not None and st.st_size > max_bytes:
            raise error(f"{what} {path} is {st.st_size:,} bytes, more than the {max_bytes:,} it can be", hint)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: str | Path, max_bytes: int, what: str = "file", **kw) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (see :func:`open_regular`)."""
    with open_regular(path, max_bytes, what, **kw) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:  # grew after the check
        raise kw.get("error", D5RLError)(
            f"{what} {path} is more than the {max_bytes:,} bytes it can be", kw.get("hint")
        )
    return data


def read_json(
    path: str | Path,
    what: str = "JSON file",
    *,
    max_bytes: int = JSON_MAX_BYTES,
    error: type[D5RLError] = D5RLError,
    hint: str | None = None,
) -> Any:
    """JSON from a bounded regular file (see :func:`open_regular`); a file that is not valid JSON, or
    nests too deeply for Python's parser, is one ``error`` line."""
    data = read_bytes(path, max_bytes, what, error=error, hint=hint)
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError) as e:
        raise error(f"{what} {path} is not valid JSON ({e})", hint) from None
    except RecursionError:
        raise error(f"{what} {path} nests too deeply to be a file d5rl wrote", hint) from None


def json_type_error(
    what: str,
    path: str | Path,
    field: str,
    value: Any,
    expected: str,
    error: type[D5RLError] = D5RLError,
    hint: str | None = None,
) -> D5RLError:
    """The one-line error for a JSON field of the wrong type or value."""
    shown = repr(value)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    return error(f"{what} {path}: {field} is {shown}, expected {expected}", hint)


def read_npz(data: bytes, where: str | Path, *, error: type[D5RLError] = D5RLError) -> dict[str, np.ndarray]:
    """The arrays of an ``np.savez`` archive held in ``data``, each member checked before it is read: stored
    uncompressed (as ``np.savez`` writes it, so no member can expand beyond the archive: no zip bomb) and
    its ``.npy`` header declaring exactly the bytes the member holds (no allocation a header merely claims)."""
    import io
    import zipfile

    def bad(msg: str) -> D5RLError:
        return error(f"{where} {msg}", "it is not an archive d5rl wrote; delete it")

    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
        members = archive.infolist()
    except (zipfile.BadZipFile, ValueError, OSError) as e:
        raise bad(f"is not a readable .npz archive ({e})") from None
    out = {}
    with archive:
        for info in members:
            if (
                not info.filename.endswith(".npy")
                or info.compress_type != zipfile.ZIP_STORED
                or info.file_size > len(data)
            ):
                raise bad(
                    f"has a member {info.filename!r} that np.savez does not write "
                    "(compressed, or larger than the archive)"
                )
            try:
                with archive.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = {
                        (1, 0): np.lib.format.read_array_header_1_0,
                        (2, 0): np.lib.format.read_array_header_2_0,
                    }.get(version)
                    if read_header is None:
                        raise bad(f"member {info.filename!r} has .npy version {version}")
                    shape, fortran, dtype = read_header(f, max_header_size=10_000)
                    header = f.tell()
                    if dtype.hasobject:
                        raise bad(f"member {info.filename!r} holds Python objects")
                    if header + math.prod(shape) * dtype.itemsize != info.file_size:
                        raise bad(
                            f"member {info.filename!r} declares shape {shape} {dtype}, which is not "
                            f"the {info.file_size - header:,} bytes it holds"
                        )
                    arr = np.frombuffer(f.read(info.file_size - header), dtype=dtype)
            except (ValueError, OSError, zipfile.BadZipFile, EOFError) as e:
                raise bad(f"member {info.filename!r} is unreadable ({e})") from None
            out[info.filename[:-4]] = (arr.reshape(shape, order="F" if fortran else "C")).copy()
    return out
