"""Advisory locks on a dataset directory, so that generators and readers never break each other.

Two lock files live in a dataset's root (``fcntl.flock``; released by the kernel when their
process dies, so a killed run never leaves a stale lock):

- ``.write.lock``: held exclusively for a whole generation run or render-cache build.  A
  second ``d5rl generate`` of the same dataset waits for the first (saying so), then finds
  the work done instead of racing it.
- ``.read.lock``: readers hold it *shared* while they read the manifest and open the shards;
  a writer holds it *exclusively* only for the instant it publishes a shard or the manifest.
  A reader therefore always sees a manifest and shards that belong together, and the arrays
  it has opened stay valid (replaced files live on while they are mapped).

Locks are re-entrant within a thread (nested calls do not deadlock on themselves); other
threads and processes wait.  On NFS, ``flock`` is emulated by POSIX locks.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from d5rl.errors import D5RLError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no locking (MuJoCo's EGL path is Linux-only anyway)
    fcntl = None

WRITE_LOCK, READ_LOCK = ".write.lock", ".read.lock"

_held: dict[tuple[str, str, int], list] = {}  # (path, file, thread) -> [fd, exclusive, count]
_mutex = threading.RLock()


@contextlib.contextmanager
def _flock(root: Path, name: str, exclusive: bool, waiting: str | None = None) -> Iterator[None]:
    if fcntl is None:
        yield
        return
    root.mkdir(parents=True, exist_ok=True)
    key = (str(root.resolve()), name, threading.get_ident())
    with _mutex:
        entry = _held.get(key)
        if entry is not None and (entry[1] or not exclusive):  # already held strongly enough here
            entry[2] += 1
            reentered = True
        else:
            reentered = False
    if reentered:
        try:
            yield
        finally:
            with _mutex:
                _held[key][2] -= 1
        return
    if entry is not None:  # held shared by this thread, exclusive wanted: would deadlock on itself
        raise RuntimeError(f"{root / name} is held shared by this thread; cannot take it exclusively")
    fd = os.open(root / name, os.O_RDWR | os.O_CREAT, 0o644)
    mode = fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH
    try:
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
        except BlockingIOError:
            if name == WRITE_LOCK:
                _refuse_waiting_on_parent(root)
            if waiting:
                print(waiting, file=sys.stderr, flush=True)
            fcntl.flock(fd, mode)  # interruptible by Ctrl-C
        if exclusive and name == WRITE_LOCK:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        with _mutex:
            _held[key] = [fd, exclusive, 1]
        try:
            yield
        finally:
            with _mutex:
                del _held[key]
    finally:
        os.close(fd)  # releases the lock


def _refuse_waiting_on_parent(root: Path) -> None:
    """A worker process re-running its parent's main script (a d5rl worker does when a task names something
    the script defines, as ``spawn`` does; see :mod:`d5rl.parallel`), for a script without
    ``if __name__ == "__main__":``, would wait forever for the lock its parent holds while it waits
    for this worker: stop it with the fix instead."""
    import multiprocessing as mp

    if _writer(root) == os.getppid() and getattr(mp.current_process(), "_inheriting", False):
        err = D5RLError(
            "a d5rl worker process re-ran the main script, which calls d5rl at top level",
            'put the script\'s code under `if __name__ == "__main__":` (worker processes import '
            "the main script), or pass workers=1",
        )
        # One line, not a traceback of the main script's import; the parent reports the exit.
        print(f"d5rl: error: {err}", file=sys.stderr, flush=True)
        raise SystemExit(1)


def _writer(root: Path) -> int | None:
    """The pid the write lock's file names (its last holder), None if it names none (missing, empty: a
    writer between creating and filling it, or garbage)."""
    try:
        return int((root / WRITE_LOCK).read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def writing(root: str | Path, what: str = "generation") -> contextlib.AbstractContextManager:
    """Exclusive right to write into ``root`` (held for a whole run; others wait)."""
    root = Path(root)
    pid = _writer(root)
    owner = "" if pid is None else f" (pid {pid})"
    return _flock(root, WRITE_LOCK, True, f"waiting for another d5rl process{owner} that is writing {root} ...")


def reading(root: str | Path) -> contextlib.AbstractContextManager:
    """Shared: the manifest and shards read inside do not change underneath."""
    return _flock(Path(root), READ_LOCK, False)


def publishing(root: str | Path) -> contextlib.AbstractContextManager:
    """Exclusive, briefly: replace a shard or the manifest while no reader is opening them."""
    return _flock(Path(root), READ_LOCK, True)
