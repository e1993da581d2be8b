"""Local backends of the executor: tasks in this process, or in worker processes on this machine."""

from __future__ import annotations

import contextlib
import os
import pickle
import subprocess
import sys
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from d5rl.parallel.process import (
    WORKER,
    Finished,
    Setup,
    error_line,
    needs_main,
    preparation,
    reporting_to,
    run_task,
)


class InProcess:
    """Tasks run in this process, one at a time, as they are submitted (no pickling; easiest to debug)."""

    def __init__(self, setup: Setup, on_message: Callable[[Any], None] | None):
        self._setup, self._on_message = setup, on_message
        self._initialized = setup.initializer is None
        self._done: list[Finished] = []

    @property
    def free(self) -> bool:
        return not self._done

    @property
    def running(self) -> int:
        return len(self._done)

    def submit(self, key, fn: Callable | str, args: tuple) -> None:
        try:
            with reporting_to(self._on_message):
                if not self._initialized:
                    self._setup.initializer(*self._setup.initargs)
                    self._initialized = True
                self._done.append(Finished(key, run_task(fn, args)))
        except Exception as e:  # noqa: BLE001 - the task's failure, reported to the caller
            self._done.append(Finished(key, error=error_line(e), traceback=traceback.format_exc(), exception=e))

    def wait(self) -> list[Finished]:
        done, self._done = self._done, []
        return done

    def close(self) -> None:
        self._done.clear()


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker process (attached as ``__cause__``)."""


class _Worker:
    """One worker process (:func:`d5rl.parallel.process.main`) and the pipes to it."""

    def __init__(self, label: str, env: dict[str, str], start: dict, init: tuple):
        to_child, inbox = os.pipe()  # (read end, write end)
        outbox, from_child = os.pipe()
        argv = [sys.executable, "-c", WORKER, str(os.getpid()), str(to_child), str(from_child), label]
        try:  # the label (the task's key, or the worker's number) tells which is which in `ps`
            self.proc = subprocess.Popen(argv, env=env, pass_fds=(to_child, from_child))
        except BaseException:
            os.close(inbox)
            os.close(outbox)
            raise
        finally:
            os.close(to_child)
            os.close(from_child)
        self.inbox, self.outbox = Connection(inbox, readable=False), Connection(outbox, writable=False)
        self.key, self.has_main = None, start["main"]
        with contextlib.suppress(OSError):  # one that died at once is reported by wait()
            self.inbox.send({k: v for k, v in start.items() if k != "main"})
            self.inbox.send(init)

    def died(self) -> str:
        """Why this process ended (it closed its pipe)."""
        try:
            code = self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        return f"killed by signal {-code}" if code < 0 else f"exit code {code}"

    def stop(self) -> None:
        """Ask an idle worker to end, or stop a busy one's task (SIGTERM: it cleans up as on Ctrl-C)."""
        if self.proc.poll() is not None:
            return
        if self.key is None:
            with contextlib.suppress(OSError):
                self.inbox.send(None)
        else:
            self.proc.terminate()

    def reap(self) -> None:
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5)
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for conn in (self.inbox, self.outbox):
            conn.close()


class LocalProcesses:
    """Tasks in at most ``n`` worker processes on this machine: each a fresh interpreter that dies with this
    process; with ``fresh`` one process per task (clean JAX and GL state, memory freed), otherwise each runs
    task after task (its :class:`~d5rl.parallel.process.Setup` paid once)."""

    def __init__(self, n: int, setup: Setup, fresh: bool, worker_env, on_message: Callable[[Any], None] | None):
        self.n, self._setup, self._fresh, self._on_message = int(n), setup, bool(fresh), on_message
        self._env = dict(os.environ, **(worker_env or {}))
        pkg_root = str(Path(__file__).resolve().parents[2])  # so the worker imports this d5rl
        path = [p for p in self._env.get("PYTHONPATH", "").split(os.pathsep) if p]
        self._env["PYTHONPATH"] = os.pathsep.join([pkg_root, *path])
        self._init_main = needs_main(setup.initializer, setup.initargs)
        self._idle: list[_Worker] = []
        self._busy: dict[Connection, _Worker] = {}
        self._ending: list[_Worker] = []
        self._done: list[Finished] = []
        self._started = 0

    @property
    def free(self) -> bool:
        return len(self._busy) < self.n

    @property
    def running(self) -> int:
        return len(self._busy) + len(self._done)

    def _worker(self, key) -> _Worker:
        if self._idle:
            return self._idle.pop()
        self._started += 1
        label = str(key) if self._fresh else f"d5rl-worker-{self._started}"
        start = {
            "single_thread": self._setup.single_thread,
            "nice": self._setup.nice,
            "preparation": preparation(self._init_main),
            "main": self._init_main,
        }
        return _Worker(label, self._env, start, (None, pickle.dumps((self._setup.initializer, self._setup.initargs))))

    def submit(self, key, fn: Callable | str, args: tuple) -> None:
        worker = self._worker(key)
        worker.key = key
        self._busy[worker.outbox] = worker
        main = preparation(True) if not worker.has_main and needs_main(fn, args) else None
        try:
            worker.inbox.send((main, pickle.dumps((fn, args))))
            if self._fresh:
                worker.inbox.send(None)  # and end after it
        except OSError:  # it died before its task arrived: wait() reports it
            return
        worker.has_main = worker.has_main or main is not None

    def wait(self) -> list[Finished]:
        """The tasks that finished since the last call (blocks until at least one has, while any runs)."""
        while not self._done and self._busy:
            for conn in wait(list(self._busy), timeout=0.25):
                self._receive(self._busy[conn])
        done, self._done = self._done, []
        return done

    def _receive(self, worker: _Worker) -> None:
        try:
            kind, payload = worker.outbox.recv()
        except (EOFError, OSError):  # it died: killed, out of memory, crashed in native code
            self._finish(worker, Finished(worker.key, error=f"worker process died ({worker.died()})"))
            return
        if kind == "msg":
            if self._on_message is not None:
                self._on_message(payload)
        elif kind == "done":
            self._finish(worker, Finished(worker.key, payload))
        else:
            exc, line, tb = payload
            cause = RemoteTraceback(tb) if exc is not None else None
            self._finish(worker, Finished(worker.key, error=line, traceback=tb, exception=exc, cause=cause))

    def _finish(self, worker: _Worker, done: Finished) -> None:
        self._done.append(done)
        del self._busy[worker.outbox]
        worker.key = None
        if self._fresh or worker.proc.poll() is not None:
            self._ending.append(worker)  # a fresh worker ends after its task
        else:
            self._idle.append(worker)
        for w in [w for w in self._ending if w.proc.poll() is not None]:
            self._ending.remove(w)
            w.reap()

    def close(self) -> None:
        """Stop every worker (a running task gets SIGTERM, and SIGKILL 5 s later)."""
        workers = list(self._busy.values()) + self._idle + self._ending
        for worker in workers:
            worker.stop()
        for worker in workers:
            worker.reap()
        self._busy.clear()
        self._idle.clear()
        self._ending.clear()
        self._done.clear()
