"""Running one cell inside a worker process (local pool or Ray): markers, logs, failures.

:func:`execute_cell` is the only function a backend calls.  It

1. takes an exclusive lock on the cell directory (a second sweep over the same
   directory skips a cell that is running elsewhere instead of racing it);
2. returns at once if the cell's ``done`` marker exists;
3. clears what a previous, unfinished attempt of the job left behind (the runner's
   own files — ``cell.json``, ``failures.jsonl``, ... — are kept), unless the job
   declares ``job.resumable = True`` (it continues from its own checkpoint);
4. sends the job's stdout/stderr (file descriptors, so native code too) to ``log.txt``;
5. calls ``job(cell, cell_dir)``; on success writes ``done`` atomically (write to
   a temporary file, fsync, rename), on an exception appends the error and its
   traceback to ``failures.jsonl`` and ``error.txt``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import sys
import time
import traceback
from pathlib import Path

from d5rl.files import try_lock
from d5rl.registry import resolve
from d5rl.runner.grid import Cell
from d5rl.training.rundir import RUNNER_FILES, RunDir


def _cell_lock(cell_dir: Path):
    """Exclusive, non-blocking lock; yields False if another process holds it."""
    return try_lock(RunDir(cell_dir).cell_lock)


@contextlib.contextmanager
def _redirect_output(path: Path):
    """Point fds 1 and 2 (and sys.stdout/err) at ``path`` for the duration."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (*saved, fd):
            os.close(f)


def clear_job_outputs(cell_dir: Path) -> None:
    """Delete everything in a cell directory except the runner's own files."""
    for p in cell_dir.iterdir():
        if p.name in RUNNER_FILES:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


def reset_cell(cell_dir: Path) -> None:
    """Make a finished cell unfinished and empty (its results describe data the task no longer has): the
    ``done`` marker and the job's outputs go; the runner's log and failure records stay."""
    RunDir(cell_dir).done.unlink(missing_ok=True)
    clear_job_outputs(Path(cell_dir))


def record_failure(cell_dir: Path, attempt: int, error: str, tb: str, wall_s: float | None = None) -> dict:
    rec = {
        "attempt": attempt,
        "error": error,
        "traceback": tb,
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "wall_s": wall_s,
    }
    RunDir(cell_dir).add_failure(rec, f"attempt {attempt}: {error}\n\n{tb}")
    return rec


def attempt_header(key: str) -> str:
    """How the line starts that each process working on a cell writes to its log (a resumed cell has several)."""
    return f"=== {key} attempt "


def execute_cell(cell_json: dict, cell_dir: str, attempt: int = 1, capture_output: bool = True) -> dict:
    """Run one cell; returns ``{"status": "ok"|"failed"|"skipped"|"busy", ...}``.  Never raises
    for a failing job (the failure is recorded in the cell directory)."""
    cell = Cell.from_json(cell_json)
    cdir = Path(cell_dir)
    cdir.mkdir(parents=True, exist_ok=True)
    with _cell_lock(cdir) as locked:
        if not locked:
            return {"status": "busy", "key": cell.key}
        if RunDir(cdir).is_done():
            return {"status": "skipped", "key": cell.key}
        try:
            job = resolve(cell.job)
        except Exception:  # noqa: BLE001 - an unimportable job is this cell's failure
            job = None
        if not getattr(job, "resumable", False):
            clear_job_outputs(cdir)  # a fresh attempt must not mix with a half-written one
        start = time.time()
        redirect = _redirect_output(RunDir(cdir).log) if capture_output else contextlib.nullcontext()
        try:
            with redirect:
                print(
                    f"{attempt_header(cell.key)}{attempt} on {socket.gethostname()} pid {os.getpid()} "
                    f"at {time.strftime('%Y-%m-%d %H:%M:%S')}",
                    flush=True,
                )
                job = resolve(cell.job)  # again, so an import error lands in the log with its traceback
                summary = job(cell, cdir)
        except BaseException as e:
            wall = time.time() - start
            err = f"{type(e).__name__}: {e}"
            rec = record_failure(cdir, attempt, err, traceback.format_exc(), wall)
            if isinstance(e, KeyboardInterrupt):
                raise
            return {"status": "failed", "key": cell.key, "error": err, "traceback": rec["traceback"], "wall_s": wall}
        wall = time.time() - start
        done = {
            "key": cell.key,
            "attempt": attempt,
            "wall_s": wall,
            "host": socket.gethostname(),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "summary": summary if isinstance(summary, dict) else None,
        }
        RunDir(cdir).write_done(done)
        return {"status": "ok", "key": cell.key, "wall_s": wall}
