"""The Ray backend of the executor: tasks on an existing Ray cluster or on a private local instance."""

from __future__ import annotations

import contextlib
import hashlib
import pickle
import socket
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from d5rl.errors import D5RLError, MissingDependencyError
from d5rl.parallel.process import Finished, Setup, configure_worker, reporting_to, run_task


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


_INITIALIZED: set[str] = set()  # the set-ups this Ray worker process has run


def _ray_task(fn, args: tuple, setup: Setup, queue, check_file: str | None):
    """One task on a Ray worker: check the shared directory, set the process up once, run."""
    if check_file is not None and not Path(check_file).exists():
        raise D5RLError(
            f"Ray node {socket.gethostname()} cannot see {Path(check_file).parent}",
            "put the dataset directory ($D5RL_HOME) on a filesystem shared by every node, at the same path",
        )
    key = hashlib.sha256(pickle.dumps(setup)).hexdigest()
    if key not in _INITIALIZED:
        configure_worker(setup.single_thread, setup.nice)
        if setup.initializer is not None:
            setup.initializer(*setup.initargs)
        _INITIALIZED.add(key)
    with reporting_to(queue.put if queue is not None else None):
        return run_task(fn, args)


class RayTasks:
    """Tasks as Ray tasks reserving ``cpus`` and ``gpus`` each; with ``fresh`` one worker process per task.
    ``shared_dir``: a directory the tasks write to, which every node must see at the same path (checked
    before any work starts on a node)."""

    def __init__(
        self,
        address: str,
        setup: Setup,
        fresh: bool,
        cpus: float,
        gpus: float,
        worker_env: dict[str, str] | None,
        shared_dir: str | Path | None,
        on_message: Callable[[Any], None] | None,
    ):
        self._ray = connect_ray(address)
        self._setup, self._on_message = setup, on_message
        options: dict[str, Any] = {"num_cpus": cpus, "num_gpus": gpus, "max_retries": 0}  # retries are the caller's
        if fresh:
            options["max_calls"] = 1  # a fresh worker process per task (clean JAX state, freed memory)
        if worker_env:
            options["runtime_env"] = {"env_vars": dict(worker_env)}  # workers started with them
        self._remote = self._ray.remote(**options)(_ray_task)
        self._check_file = None
        if shared_dir is not None:
            check = Path(shared_dir) / f".ray-check-{uuid.uuid4().hex}"
            check.parent.mkdir(parents=True, exist_ok=True)
            check.touch()
            self._check_file = str(check.resolve())
        self._queue = None
        if on_message is not None:
            from ray.util.queue import Queue  # optional (pip install ray): only --ray runs need it

            self._queue = Queue()
        self._running: dict = {}  # ref -> key
        self._done: list[Finished] = []

    @property
    def free(self) -> bool:
        return True  # Ray queues every task

    @property
    def running(self) -> int:
        return len(self._running) + len(self._done)

    def submit(self, key, fn: Callable | str, args: tuple) -> None:
        ref = self._remote.remote(fn, args, self._setup, self._queue, self._check_file)
        self._running[ref] = key

    def _drain(self) -> None:
        if self._queue is None:
            return
        while not self._queue.empty():
            self._on_message(self._queue.get_nowait())

    def wait(self) -> list[Finished]:
        """The tasks that finished since the last call (blocks until at least one has, while any runs)."""
        while not self._done and self._running:
            ready, _ = self._ray.wait(list(self._running), num_returns=1, timeout=0.25)
            self._drain()  # a task's messages are queued before it returns
            for ref in ready:
                self._done.append(self._outcome(self._running.pop(ref), ref))
        done, self._done = self._done, []
        return done

    def _outcome(self, key, ref) -> Finished:
        try:
            return Finished(key, self._ray.get(ref))
        except Exception as e:  # noqa: BLE001 - the task's failure, a worker crash, a lost node, an unpicklable result
            exc = e
            if isinstance(e, self._ray.exceptions.RayTaskError):
                cause = e.as_instanceof_cause()
                if isinstance(cause, D5RLError):  # a user-fixable problem: keep its one-line message
                    exc = D5RLError(cause.message, cause.hint)
            line = str(e).splitlines()[0] if str(e) else ""
            return Finished(key, error=f"Ray task failed: {type(e).__name__}: {line}", traceback=str(e), exception=exc)

    def close(self) -> None:
        for ref in self._running:
            with contextlib.suppress(Exception):  # best effort on the way out
                self._ray.cancel(ref, force=True)
        self._running.clear()
        self._done.clear()
        if self._queue is not None:
            self._queue.shutdown()
        if self._check_file is not None:
            Path(self._check_file).unlink(missing_ok=True)
