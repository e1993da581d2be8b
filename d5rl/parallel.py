"""The executor: every parallel job of d5rl runs here, in this process, in local processes, or on a Ray cluster.

Two forms share the backends, the worker set-up (:func:`configure_worker`, :func:`die_with_parent`) and the Ray
connection (:func:`connect_ray`):

- :func:`run_jobs`: many short jobs on a pool of long-lived workers, results in order, progress messages
  streamed back (dataset generation and the render cache, one job per shard);
- :class:`Tasks`: long tasks, each in a fresh worker process, submitted and collected one by one so the caller
  can retry them (the cells of a ``d5rl bench`` grid).

For :func:`run_jobs` the backend is chosen by ``workers``:

- ``1``: in this process (no pickling; easiest to debug);
- ``N > 1`` or ``None`` (all cores): a ``spawn`` process pool on this machine;
- :class:`Ray` ``(address)``: tasks on an existing Ray cluster (``"auto"``, ``"ray://host:10001"``)
  or on a private local instance (``"local"``).  The jobs read and write the dataset directory,
  so it must be on a filesystem every node sees at the same path; :func:`run_jobs` checks that
  before any work starts on a node and says so if it is not.

``worker_env`` gives the worker processes variables they must start with (read by the dynamic
loader or when a library loads, e.g. :func:`d5rl.numerics.portable_env`): jobs then always run in
started processes, even with ``workers=1``, and on Ray in workers started with them.

Jobs report progress with :func:`report` (any picklable payload, e.g. one finished
episode); the driver receives it through ``on_message`` whatever the backend.

Scripts without ``if __name__ == "__main__":``: a ``spawn`` worker normally re-runs the main
script to find what it was sent; a script calling d5rl at top level would then call it again in
every worker, and wait on its own parent's dataset lock.  When nothing sent to the workers comes
from the main script (d5rl's own jobs never do), the workers are started without it; otherwise a
worker that re-runs it and reaches a d5rl lock its parent holds stops with a one-line error naming
the guard (:func:`d5rl.datasets.lock.writing`).

Stopping: on Ctrl-C or an error the driver terminates its pool workers at once (they ignore
SIGINT, so a Ctrl-C to the whole process group is handled by the driver alone), and a worker
whose driver dies, even by ``kill -9``, exits by itself (``PR_SET_PDEATHSIG`` on Linux and a
watchdog thread everywhere), so no orphan keeps writing.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib
import json
import multiprocessing as mp
import os
import pickle
import queue as queue_mod
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import types
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from d5rl.errors import D5RLError, MissingDependencyError, is_int
from d5rl.xla_flags import SINGLE_THREAD, add_xla_flags


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


# Environment of a worker: one compute thread per process, so K workers use K cores.
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "TF_CPP_MIN_LOG_LEVEL": "2",
    "XLA_PYTHON_CLIENT_PREALLOCATE": "false",  # several jobs may share one GPU
}


def configure_worker(single_thread: bool = True, nice: int = 0) -> None:
    """The per-process environment of every d5rl worker (dataset pool, bench cells), set before any
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


# --- worker side: where report() sends to --------------------------------------------------------------
_SINK: Callable[[Any], None] | None = None
_INITIALIZED: set[str] = set()


def report(payload: Any) -> None:
    """Send a progress message from inside a job to the driver's ``on_message`` (no-op without one)."""
    if _SINK is not None:
        _SINK(payload)


def _pool_worker(tasks, results, fn, initializer, initargs, parent_pid: int) -> None:
    """A pool process: run jobs from ``tasks`` until the ``None`` sentinel; report to ``results``."""
    global _SINK
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver decides what Ctrl-C means
    die_with_parent(parent_pid)
    configure_worker()  # one process per core: one compute thread each
    _SINK = lambda payload: results.put(("msg", None, payload))  # noqa: E731
    try:
        if initializer is not None:
            initializer(*initargs)
    except BaseException as e:  # noqa: BLE001 - reported to the driver
        results.put(("error", None, _portable_error(e)))
        return
    while (item := tasks.get()) is not None:
        i, job = item
        try:
            results.put(("done", i, fn(*job)))
        except BaseException as e:  # noqa: BLE001 - reported to the driver
            results.put(("error", i, _portable_error(e)))
            return


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker process (attached as ``__cause__``)."""


def _portable_error(e: BaseException) -> tuple[BaseException | None, str]:
    tb = "".join(traceback.format_exception(type(e), e, e.__traceback__))
    try:
        pickle.loads(pickle.dumps(e))
        return e, tb
    except Exception:  # noqa: BLE001 - an exception that does not survive pickling
        return None, tb


def _ray_job(fn, job, initializer, initargs, q, check_file: str | None):
    """One job on a Ray worker: check the shared directory, initialize once per process, run."""
    global _SINK
    if check_file is not None and not Path(check_file).exists():
        raise D5RLError(
            f"Ray node {socket.gethostname()} cannot see {Path(check_file).parent}",
            "put the dataset directory ($D5RL_HOME) on a filesystem shared by every node, at the same path",
        )
    key = hashlib.sha256(pickle.dumps((initializer, initargs))).hexdigest()
    if initializer is not None and key not in _INITIALIZED:
        initializer(*initargs)
        _INITIALIZED.add(key)
    _SINK = q.put
    try:
        return fn(*job)
    finally:
        _SINK = None


# --- driver side ----------------------------------------------------------------------------------------
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
    """``[fn(*job) for job in jobs]``, in parallel; results in job order.

    ``initializer(*initargs)`` runs once in each worker process before its first job
    (in this process when ``workers == 1``).  ``on_result(i, result)`` is called as
    each job finishes, so a caller can record progress that survives a later failure.
    ``shared_dir`` is a directory the jobs write to; on Ray every node must see it.
    ``worker_env``: variables every worker process starts with; with it no job runs in this process.
    """
    check_workers(workers)
    jobs = list(jobs)
    results: list = [None] * len(jobs)
    if not jobs:
        return results

    def settle(i, res):
        results[i] = res
        if on_result is not None:
            on_result(i, res)

    if isinstance(workers, Ray):
        _run_ray(fn, jobs, workers.address, initializer, initargs, on_message, settle, shared_dir, worker_env)
        return results
    n = max(1, min(int(workers or os.cpu_count() or 1), len(jobs)))
    if n == 1 and worker_env is None:
        _run_here(fn, jobs, initializer, initargs, on_message, settle)
    else:
        _run_pool(fn, jobs, n, initializer, initargs, on_message, settle, worker_env)
    return results


def _run_here(fn, jobs, initializer, initargs, on_message, settle) -> None:
    global _SINK
    if initializer is not None:
        initializer(*initargs)
    _SINK = on_message
    try:
        for i, job in enumerate(jobs):
            settle(i, fn(*job))
    finally:
        _SINK = None


def _drain(q, on_message, get) -> None:
    while True:
        try:
            msg = get()
        except queue_mod.Empty:
            return
        if on_message is not None:
            on_message(msg)


def needs_main(*payload) -> bool:
    """Whether unpickling ``payload`` in another process needs this process's ``__main__`` module."""
    try:
        return b"__main__" in pickle.dumps(payload)
    except Exception:  # noqa: BLE001 - not picklable: the pool says so when it sends it
        return True


@contextlib.contextmanager
def _without_main_script(hide: bool):
    """Start processes that do not re-run the main script (see the module docstring): ``spawn``
    records which script to re-run from ``sys.modules["__main__"]`` when a process starts."""
    main = sys.modules.get("__main__")
    if not hide or main is None:
        yield
        return
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


@contextlib.contextmanager
def _environ(extra: dict[str, str] | None):
    """``os.environ`` with ``extra`` while started processes copy it (restored afterwards)."""
    saved = {k: os.environ.get(k) for k in extra or {}}
    os.environ.update(extra or {})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_pool(fn, jobs, n, initializer, initargs, on_message, settle, worker_env=None) -> None:
    ctx = mp.get_context("spawn")  # fork is unsafe with JAX / OpenGL state in the parent
    tasks, results = ctx.SimpleQueue(), ctx.Queue()
    for i, job in enumerate(jobs):
        tasks.put((i, job))
    for _ in range(n):
        tasks.put(None)
    procs = [
        ctx.Process(
            target=_pool_worker,
            args=(tasks, results, fn, initializer, initargs, os.getpid()),
            daemon=True,
            name=f"d5rl-worker-{k}",
        )
        for k in range(n)
    ]
    with _without_main_script(not needs_main(fn, initializer, initargs, jobs)), _environ(worker_env):
        for p in procs:
            p.start()
    remaining = set(range(len(jobs)))
    try:
        while remaining:
            try:
                kind, i, payload = results.get(timeout=0.25)
            except queue_mod.Empty:
                dead = [p for p in procs if p.exitcode not in (None, 0)]
                if dead:
                    raise D5RLError(
                        f"a worker process died (exit code {dead[0].exitcode}) before finishing its job",
                        "its error, if it had time to print one, is above; otherwise look for an "
                        "out-of-memory kill (dmesg); run the same command again to resume",
                    ) from None
                continue
            if kind == "msg":
                if on_message is not None:
                    on_message(payload)
            elif kind == "done":
                remaining.discard(i)
                settle(i, payload)
            else:
                exc, tb = payload
                if exc is None:
                    raise RuntimeError(f"a worker failed:\n{tb}")
                raise exc from RemoteTraceback(tb)
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
                p.join()
        results.close()
    # Each worker sends its progress messages before its result, through one queue, so when the
    # last result has arrived no message is still on its way.


def import_ray():
    try:
        import ray  # optional (pip install ray): only --ray runs need it
    except ImportError as e:
        raise MissingDependencyError(
            "the Ray backend needs the `ray` package",
            "pip install 'ray>=2.9' (or run without --ray to use the local process pool)",
        ) from e
    return ray


def connect_ray(address: str | None):
    """``ray`` after making sure it is connected (``"local"`` starts a private instance)."""
    ray = import_ray()
    if not ray.is_initialized():
        try:
            if address == "local":
                ray.init(log_to_driver=False, include_dashboard=False)
            else:
                ray.init(address=address or "auto", log_to_driver=False)
        except ConnectionError as e:
            raise D5RLError(
                f"cannot reach a Ray cluster at {address or 'auto'} ({e})",
                "start one with `ray start --head` or pass --ray ADDRESS of a running head node",
            ) from e
        except ValueError as e:
            if "ray[client]" not in str(e):
                raise
            raise MissingDependencyError(
                f"--ray {address} connects through Ray Client, which is not installed",
                "pip install 'ray[client]', or run on the head node with --ray auto",
            ) from None
    return ray


def _run_ray(fn, jobs, address, initializer, initargs, on_message, settle, shared_dir, worker_env=None) -> None:
    ray = connect_ray(address)
    from ray.util.queue import Queue  # optional (pip install ray): only --ray runs need it

    check_file = None
    if shared_dir is not None:
        check = Path(shared_dir) / f".ray-check-{uuid.uuid4().hex}"
        check.parent.mkdir(parents=True, exist_ok=True)
        check.touch()
        check_file = str(check.resolve())
    q = Queue()
    options = {"runtime_env": {"env_vars": dict(worker_env)}} if worker_env else {}  # workers started with them
    remote = ray.remote(num_cpus=1, max_retries=0, **options)(_ray_job)
    refs = {remote.remote(fn, job, initializer, initargs, q, check_file): i for i, job in enumerate(jobs)}
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1, timeout=0.25)
            _drain(q, on_message, q.get_nowait)
            for ref in done:
                i = refs.pop(ref)
                try:
                    res = ray.get(ref)
                except ray.exceptions.RayTaskError as e:
                    cause = e.as_instanceof_cause()
                    if isinstance(cause, D5RLError):  # a user-fixable problem: keep its one-line message
                        raise D5RLError(cause.message, cause.hint) from None
                    raise
                settle(i, res)
        _drain(q, on_message, q.get_nowait)
    finally:
        for ref in refs:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        q.shutdown()
        if check_file is not None:
            Path(check_file).unlink(missing_ok=True)


# --- one task per fresh process: bench cells --------------------------------------------------------------
@dataclass
class Finished:
    """How one task of :class:`Tasks` ended: what it returned, or why it did not (``error``, a line, and
    ``traceback``, the details: the task's traceback or the backend's error)."""

    key: Any
    value: Any = None
    error: str | None = None
    traceback: str = ""


class Tasks:
    """Tasks ``fn(*args)`` (``fn`` named ``"module:function"``), each in a fresh worker process, on one backend:

    - ``workers=0``: in this process, one after another (for debugging);
    - ``workers=N``: at most N local processes at once, each a fresh interpreter (``python -m d5rl.parallel``:
      no inherited JAX or GL state, no re-run of the caller's ``__main__``) that dies with this process;
    - :class:`Ray` ``(address)``: Ray tasks reserving ``cpus`` and ``gpus`` each, one worker process per task.

    Workers start with :func:`configure_worker` (``single_thread``, ``nice``) before anything else is imported.
    The caller submits tasks while :attr:`free`, and :meth:`wait` returns those that finished; a task that
    failed can be submitted again.  Leaving the ``with`` block stops the tasks still running.
    """

    def __init__(self, workers: int | Ray, *, single_thread: bool = True, nice: int = 0, cpus=1.0, gpus=0.0):
        self.workers, self.single_thread, self.nice = workers, bool(single_thread), int(nice)
        self._done: list[Finished] = []
        self._running: dict = {}  # local: Popen -> (key, result pipe); Ray: ref -> key
        if isinstance(workers, Ray):
            self._ray = connect_ray(workers.address)
            # max_calls=1: a fresh worker process per task (clean JAX state, freed memory), as locally;
            # retries are the caller's, so Ray's are off
            self._remote = self._ray.remote(num_cpus=cpus, num_gpus=gpus, max_calls=1, max_retries=0)(_call)

    @property
    def free(self) -> bool:
        """Whether a task submitted now starts at once (Ray queues every task: always)."""
        if isinstance(self.workers, Ray):
            return True
        return not self._done if self.workers == 0 else len(self._running) < int(self.workers)

    @property
    def running(self) -> int:
        return len(self._running) + len(self._done)

    def submit(self, key, fn: str, *args) -> None:
        if isinstance(self.workers, Ray):
            ref = self._remote.remote(fn, args, self.single_thread, self.nice)
            self._running[ref] = key
        elif self.workers == 0:
            self._done.append(_finished(key, lambda: resolve_name(fn)(*args)))
        else:
            self._running[self._start(key, fn, args)] = key

    def _start(self, key, fn: str, args: tuple):
        spec = {"fn": fn, "args": args, "single_thread": self.single_thread, "nice": self.nice}
        spec["sys_path"] = [p for p in sys.path if p]  # the caller's import path (its jobs, test modules)
        env = dict(os.environ)
        pkg_root = str(Path(__file__).resolve().parents[1])  # so the worker imports this d5rl
        env["PYTHONPATH"] = os.pathsep.join([pkg_root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        fd, result = tempfile.mkstemp(prefix="d5rl-task-", suffix=".json")
        os.close(fd)
        argv = [sys.executable, "-c", _WORKER, result, str(os.getpid()), str(key)]  # the key: which task, in `ps`
        proc = subprocess.Popen(argv, env=env, stdin=subprocess.PIPE)
        proc.stdin.write(json.dumps(spec).encode())
        proc.stdin.close()
        proc.result_path = Path(result)
        return proc

    def wait(self) -> list[Finished]:
        """The tasks that finished since the last call (blocks until at least one has, while any runs)."""
        while not self._done and self._running:
            if isinstance(self.workers, Ray):
                ready, _ = self._ray.wait(list(self._running), num_returns=1)
                for ref in ready:
                    key = self._running.pop(ref)
                    self._done.append(_finished(key, lambda ref=ref: self._ray.get(ref), remote=True))
                continue
            ended = [p for p in self._running if p.poll() is not None]
            if not ended:
                time.sleep(0.05)
            for proc in ended:
                self._done.append(_read_result(self._running.pop(proc), proc))
        done, self._done = self._done, []
        return done

    def close(self) -> None:
        if isinstance(self.workers, Ray):
            for ref in self._running:
                with contextlib.suppress(Exception):
                    self._ray.cancel(ref, force=True)
        else:
            for proc in self._running:
                proc.terminate()
            for proc in self._running:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(5)
                proc.result_path.unlink(missing_ok=True)
        self._running.clear()

    def __enter__(self) -> Tasks:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def resolve_name(name: str) -> Callable:
    """The function ``"package.module:function"`` names."""
    module, _, attr = name.partition(":")
    return getattr(importlib.import_module(module), attr)


def _finished(key, call: Callable[[], Any], remote: bool = False) -> Finished:
    try:
        return Finished(key, call())
    except Exception as e:  # noqa: BLE001 - the task's failure, reported to the caller
        if remote:  # a worker crash, a lost node, an unpicklable result
            line = str(e).splitlines()[0] if str(e) else ""
            return Finished(key, error=f"Ray task failed: {type(e).__name__}: {line}", traceback=str(e))
        return Finished(key, error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())


def _read_result(key, proc) -> Finished:
    data = ""
    with contextlib.suppress(OSError):
        data = proc.result_path.read_text()
    proc.result_path.unlink(missing_ok=True)
    if proc.returncode == 0 and data:
        return Finished(key, **json.loads(data))
    code = proc.returncode
    how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
    return Finished(key, error=f"worker process died ({how})")


def _call(fn: str, args: tuple, single_thread: bool, nice: int):
    """A task in a Ray worker process."""
    configure_worker(single_thread, nice)
    return resolve_name(fn)(*args)


_WORKER = "import sys; from d5rl.parallel import _task_main; sys.exit(_task_main(sys.argv[1:]))"


def _task_main(argv: list[str]) -> int:
    """One task of :class:`Tasks` in this fresh process (``argv``: the result file, the caller's pid, the task's
    key): its spec read from stdin, its result written as JSON (``{"value": ...}`` or ``{"error": ..., "traceback": ...}``)."""
    die_with_parent(int(argv[1]))  # no orphan races the caller's next attempt, even if the caller died first
    spec = json.loads(sys.stdin.buffer.read())
    configure_worker(spec["single_thread"], spec["nice"])  # before JAX is imported
    for p in reversed(spec["sys_path"]):
        if p not in sys.path:
            sys.path.insert(0, p)
    done = _finished(None, lambda: resolve_name(spec["fn"])(*spec["args"]))
    out = {"value": done.value} if done.error is None else {"error": done.error, "traceback": done.traceback}
    Path(argv[0]).write_text(json.dumps(out, default=str))
    return 0
