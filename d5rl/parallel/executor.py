"""The executor (:class:`Executor`) and its batch form (:func:`run_jobs`); see :mod:`d5rl.parallel`."""

from __future__ import annotations

import collections
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from d5rl.errors import D5RLError, is_int
from d5rl.parallel.cluster import RayTasks
from d5rl.parallel.local import InProcess, LocalProcesses
from d5rl.parallel.process import Finished, Setup


@dataclass(frozen=True)
class Ray:
    """Run on a Ray cluster: ``"auto"`` (the one this machine belongs to), ``"ray://HOST:PORT"``,
    or ``"local"`` (start a private instance on this machine)."""

    address: str = "auto"


Workers = int | Ray | None


def check_workers(workers: Workers) -> None:
    """One-line error for a worker count that is not a positive integer (None = all cores)."""
    if workers is None or isinstance(workers, Ray):
        return
    if not is_int(workers, lo=1):
        raise D5RLError(
            f"workers must be a positive number of processes, got {workers!r}",
            "omit --workers to use every core, or pass --workers 1 to run in this process",
        )


class Executor:
    """Tasks ``fn(*args)`` (``fn`` a function or the ``"module:function"`` naming one) on one backend:

    - ``workers=0``: in this process, one after another as they are submitted (for debugging);
    - ``workers=N``: at most N worker processes on this machine, each a fresh interpreter that dies with this
      process; with ``fresh`` one process per task, otherwise each runs task after task;
    - :class:`Ray` ``(address)``: Ray tasks reserving ``cpus`` and ``gpus`` each (``fresh``: one worker process
      per task); ``shared_dir``, a directory the tasks write to, must be seen by every node (checked).

    Every worker process starts with :func:`~d5rl.parallel.process.configure_worker` (``single_thread``,
    ``nice``) before anything else is imported, and ``worker_env`` in its environment (variables read when a
    library loads), then runs ``initializer(*initargs)`` once before its first task.  A task's
    :func:`~d5rl.parallel.process.report` messages reach ``on_message`` in this process.

    The caller submits tasks while :attr:`free`, and :meth:`wait` returns those that finished as
    :class:`~d5rl.parallel.process.Finished`; a task that failed can be submitted again.  Leaving the ``with``
    block (also by Ctrl-C or an error) stops the tasks still running.
    """

    def __init__(
        self,
        workers: int | Ray,
        *,
        fresh: bool = False,
        single_thread: bool = True,
        nice: int = 0,
        cpus: float = 1.0,
        gpus: float = 0.0,
        initializer: Callable | None = None,
        initargs: tuple = (),
        worker_env: dict[str, str] | None = None,
        shared_dir: str | Path | None = None,
        on_message: Callable[[Any], None] | None = None,
    ):
        setup = Setup(bool(single_thread), int(nice), initializer, tuple(initargs))
        if isinstance(workers, Ray):
            self._backend = RayTasks(workers.address, setup, fresh, cpus, gpus, worker_env, shared_dir, on_message)
        elif workers == 0:
            if worker_env:
                raise ValueError("worker_env needs worker processes: workers must be at least 1")
            self._backend = InProcess(setup, on_message)
        else:
            self._backend = LocalProcesses(int(workers), setup, fresh, worker_env, on_message)

    @property
    def free(self) -> bool:
        """Whether a task submitted now starts at once (Ray queues every task: always)."""
        return self._backend.free

    @property
    def running(self) -> int:
        """Tasks submitted and not yet returned by :meth:`wait`."""
        return self._backend.running

    def submit(self, key, fn: Callable | str, *args) -> None:
        self._backend.submit(key, fn, args)

    def wait(self) -> list[Finished]:
        """The tasks that finished since the last call (blocks until at least one has, while any runs)."""
        return self._backend.wait()

    def close(self) -> None:
        self._backend.close()

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def reraise(done: Finished) -> None:
    """Raise in this process what made a task fail."""
    if done.exception is None:
        raise D5RLError(
            f"a {done.error} before finishing its job" if done.error.startswith("worker process") else done.error,
            "its error, if it had time to print one, is above; otherwise look for an "
            "out-of-memory kill (dmesg); run the same command again to resume",
        )
    if done.cause is None:
        raise done.exception
    raise done.exception from done.cause


def run_jobs(
    fn: Callable,
    jobs: Sequence[tuple],
    *,
    workers: Workers = None,
    initializer: Callable | None = None,
    initargs: tuple = (),
    on_message: Callable[[Any], None] | None = None,
    on_result: Callable[[int, Any], None] | None = None,
    shared_dir: str | Path | None = None,
    worker_env: dict[str, str] | None = None,
) -> list:
    """``[fn(*job) for job in jobs]`` on an :class:`Executor` of long-lived workers; results in job order, the
    first failure raised here (the other jobs are stopped).

    ``workers``: ``1`` runs the jobs in this process (unless ``worker_env`` is given), ``N`` in N processes,
    ``None`` in one per core, :class:`Ray` on a cluster.  ``on_result(i, result)`` is called as each job
    finishes, so a caller can record progress that survives a later failure; the rest is :class:`Executor`'s.
    """
    check_workers(workers)
    jobs = list(jobs)
    results: list = [None] * len(jobs)
    if not jobs:
        return results
    if isinstance(workers, Ray):
        backend: int | Ray = workers
    else:
        n = max(1, min(int(workers or os.cpu_count() or 1), len(jobs)))
        backend = 0 if n == 1 and worker_env is None else n
    todo = collections.deque(enumerate(jobs))
    options = {"initializer": initializer, "initargs": initargs, "on_message": on_message}
    with Executor(backend, worker_env=worker_env, shared_dir=shared_dir, **options) as executor:
        while todo or executor.running:
            while todo and executor.free:
                i, job = todo.popleft()
                executor.submit(i, fn, *job)
            for done in executor.wait():
                if done.error is not None:
                    reraise(done)
                results[done.key] = done.value
                if on_result is not None:
                    on_result(done.key, done.value)
    return results
