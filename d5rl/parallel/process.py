"""The worker side of the executor: how every d5rl worker process starts, runs its tasks and reports.

A local worker is a fresh interpreter (``python -c`` :data:`WORKER`) that :mod:`d5rl.parallel.local` starts with two
pipes.  It reads, in order: its set-up (plain values: one compute thread or not, niceness, the caller's import
path and working directory), then the initializer, then tasks until ``None``; it writes, per task, the
:func:`report` messages the task sent and then ``("done", value)`` or ``("error", ...)``.  Its set-up runs before
anything it is sent is unpickled, so no numerical library is imported before its thread count is set.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import multiprocessing as mp
import multiprocessing.spawn
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from d5rl.xla_flags import SINGLE_THREAD, add_xla_flags

# The program of a local worker process (its arguments: the caller's pid, the two pipes, a label for `ps`).
WORKER = "import sys; from d5rl.parallel.process import main; sys.exit(main(sys.argv[1:]))"

# Environment of a worker: one compute thread per process, so K workers use K cores.
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "TF_CPP_MIN_LOG_LEVEL": "2",
    "XLA_PYTHON_CLIENT_PREALLOCATE": "false",  # several jobs may share one GPU
}


def configure_worker(single_thread: bool = True, nice: int = 0) -> None:
    """The per-process environment of every d5rl worker (dataset shards, bench cells), set before any
    numerical library is imported: one compute thread (unless asked otherwise), optional niceness."""
    if single_thread:
        add_xla_flags(*SINGLE_THREAD)
        for k, v in SINGLE_THREAD_ENV.items():
            os.environ.setdefault(k, v)
    if nice:
        with contextlib.suppress(OSError):
            os.nice(nice)


def die_with_parent(parent_pid: int | None = None) -> None:
    """Make this process exit when its parent dies, however it dies (no orphans)."""
    parent_pid = os.getppid() if parent_pid is None else parent_pid
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)

    def watch():
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, daemon=True, name="d5rl-parent-watchdog").start()


@dataclass(frozen=True)
class Setup:
    """How every worker process of one executor starts: :func:`configure_worker` (``single_thread``, ``nice``),
    then ``initializer(*initargs)`` once, before its first task."""

    single_thread: bool = True
    nice: int = 0
    initializer: Callable | None = None
    initargs: tuple = ()


# --- where report() sends to ----------------------------------------------------------------------------------
_SINK: Callable[[Any], None] | None = None


def report(payload: Any) -> None:
    """Send a progress message from inside a task to the executor's ``on_message`` (no-op without one)."""
    if _SINK is not None:
        _SINK(payload)


@contextlib.contextmanager
def reporting_to(sink: Callable[[Any], None] | None):
    """:func:`report` calls go to ``sink`` inside this block."""
    global _SINK
    _SINK = sink
    try:
        yield
    finally:
        _SINK = None


def resolve_name(name: str) -> Callable:
    """The function ``"package.module:function"`` names."""
    module, _, attr = name.partition(":")
    return getattr(importlib.import_module(module), attr)


def run_task(fn: Callable | str, args: tuple) -> Any:
    """``fn(*args)``; ``fn`` a function or the ``"module:function"`` naming one."""
    return (resolve_name(fn) if isinstance(fn, str) else fn)(*args)


def error_line(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


@dataclass
class Finished:
    """How one task ended: what it returned (``value``), or why it did not: ``error`` (a line), ``traceback`` (the
    task's traceback or the backend's error) and ``exception`` (the exception to raise in the driver, when it
    could be carried there; ``cause``: the remote traceback to chain it to)."""

    key: Any
    value: Any = None
    error: str | None = None
    traceback: str = ""
    exception: BaseException | None = None
    cause: BaseException | None = None


def portable_error(e: BaseException) -> tuple[BaseException | None, str, str]:
    """``(e or None, its line, its traceback)``: ``e`` itself when it survives pickling to the driver."""
    tb = "".join(traceback.format_exception(type(e), e, e.__traceback__))
    try:
        pickle.loads(pickle.dumps(e))
        return e, error_line(e), tb
    except Exception:  # noqa: BLE001 - an exception that does not survive pickling
        return None, error_line(e), tb


# --- the caller's main script -----------------------------------------------------------------------------------
# A fresh worker does not run the caller's main script, so a script without `if __name__ == "__main__":` is not
# run again in every worker.  Only a task (or initializer) that names something defined in the main script needs
# it: the worker then loads it the way a `spawn` process does (and d5rl.datasets.lock stops a worker whose
# re-run of an unguarded script reaches a lock its caller holds, with the fix).
MAIN_KEYS = ("init_main_from_name", "init_main_from_path")


def needs_main(*payload) -> bool:
    """Whether unpickling ``payload`` in another process needs this process's ``__main__`` module."""
    try:
        return b"__main__" in pickle.dumps(payload)
    except Exception:  # noqa: BLE001 - not picklable: sending it says so
        return True


def preparation(with_main: bool) -> dict:
    """What a worker needs to import what this process sends it: its import path and working directory, and
    with ``with_main`` its main script (plain values only, as ``multiprocessing``'s ``spawn`` sends them)."""
    data = mp.spawn.get_preparation_data("d5rl-worker")
    keep = ("sys_path", "sys_argv", "dir", "orig_dir") + (MAIN_KEYS if with_main else ())
    return {k: v for k, v in data.items() if k in keep}


def _prepare(data: dict) -> None:
    process = mp.current_process()
    process._inheriting = True  # what spawn sets while it loads the main script (d5rl.datasets.lock reads it)
    try:
        mp.spawn.prepare(data)
    finally:
        del process._inheriting


# --- a local worker process ---------------------------------------------------------------------------------------
def _stop(signum, frame):
    raise KeyboardInterrupt  # the driver stops a task with SIGTERM: the task cleans up as on Ctrl-C


def main(argv: list[str]) -> int:
    """A local worker process (``argv``: the caller's pid, the pipe to read, the pipe to write, a label)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver decides what Ctrl-C means
    signal.signal(signal.SIGTERM, _stop)
    die_with_parent(int(argv[0]))  # no orphan races the caller's next attempt, even if the caller died first
    inbox, outbox = Connection(int(argv[1]), writable=False), Connection(int(argv[2]), readable=False)
    try:
        return _serve(inbox, outbox)
    except (KeyboardInterrupt, EOFError, BrokenPipeError):  # stopped by the driver, or the driver is gone
        return 1


def _serve(inbox: Connection, outbox: Connection) -> int:
    start = inbox.recv()  # plain values: unpickling them imports nothing
    configure_worker(start["single_thread"], start["nice"])  # before anything is imported
    _prepare(start["preparation"])
    main_loaded = any(k in start["preparation"] for k in MAIN_KEYS)

    def load(item: tuple[dict | None, bytes]):
        """What the driver sent: the main script to load first if it is needed and not loaded yet, and a
        pickled payload."""
        nonlocal main_loaded
        main, blob = item
        if main is not None and not main_loaded:
            _prepare(main)
            main_loaded = True
        return pickle.loads(blob)

    init_error = None
    try:
        initializer, initargs = load(inbox.recv())
        if initializer is not None:
            initializer(*initargs)
    except Exception as e:  # noqa: BLE001 - every task of this worker fails with it
        init_error = portable_error(e)
    while (item := inbox.recv()) is not None:
        if init_error is not None:
            outbox.send(("error", init_error))
            return 1
        try:
            fn, args = load(item)
            with reporting_to(lambda payload: outbox.send(("msg", payload))):
                value = run_task(fn, args)
            outbox.send(("done", value))
        except Exception as e:  # noqa: BLE001 - the task's failure, reported to the driver
            outbox.send(("error", portable_error(e)))
    return 0
