"""Run a benchmark grid locally (one process per cell) or on a Ray cluster.

    result = run_bench(expand_grid(["a1-walk-v0"], ["bc", "iql"], [0, 1, 2], 500_000, 0), "runs/a1")

Idempotent: a cell with a ``done`` marker is skipped, so a killed sweep resumes
by running the same command again.  A failing cell is recorded (error and
traceback in its directory) and retried once (``max_attempts=2``).  A finished cell
whose job recorded a dataset that is no longer the task's (a new dataset or generator
version) is stale: the same command trains it again, so a grid follows its data.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from d5rl.errors import D5RLError
from d5rl.files import write_atomic
from d5rl.parallel import configure_worker, connect_ray
from d5rl.runner.execute import EXIT_CODES, clear_job_outputs, execute_cell, record_failure, reset_cell
from d5rl.runner.grid import DEFAULT_JOB, Cell, GridError, read_cell, same_run, stale_reason
from d5rl.training.rundir import BENCH_LOG, RunDir


@dataclasses.dataclass
class BenchResult:
    run_dir: Path
    ok: list[str] = dataclasses.field(default_factory=list)  # cells finished in this invocation
    skipped: list[str] = dataclasses.field(default_factory=list)  # already done before
    failed: dict[str, str] = dataclasses.field(default_factory=dict)  # key -> last error
    busy: list[str] = dataclasses.field(default_factory=list)  # running in another sweep
    stale: list[str] = dataclasses.field(default_factory=list)  # finished on older data, trained again now
    attempts: dict[str, int] = dataclasses.field(default_factory=dict)  # key -> attempts made now
    wall_s: float = 0.0

    def summary(self) -> str:
        s = (
            f"{len(self.ok)} finished, {len(self.skipped)} already done, {len(self.failed)} failed"
            f"{f', {len(self.busy)} running elsewhere' if self.busy else ''}"
            f"{f', {len(self.stale)} rerun on new data' if self.stale else ''} in {self.wall_s:.1f} s"
        )
        for key, err in self.failed.items():
            s += f"\n  FAILED {key}: {err.splitlines()[0] if err else ''}\n    see {RunDir(self.run_dir / key).error}"
        return s


def default_workers() -> int:
    with contextlib.suppress(AttributeError):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def prepare(cells: Iterable[Cell], run_dir: Path | str, argv: list[str] | None = None) -> list[Cell]:
    """Write each cell's ``cell.json`` (refusing to redefine a finished cell) and log the launch."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cells = list(cells)
    for cell in cells:
        cdir = cell.directory(run_dir)
        old, done = read_cell(cdir), RunDir(cdir).is_done()
        if old is not None and not same_run(old, cell) and done:
            diff = {k: (v, getattr(cell, k)) for k, v in old.to_json().items() if v != getattr(cell, k)}
            raise GridError(
                f"cell {cell.key} in {run_dir} already finished with other settings: {diff}",
                "write this grid to a new --out directory, or delete that cell's directory to rerun it",
            )
        if old != cell and not done:  # a finished cell keeps the record of how it ran
            if old is not None and not same_run(old, cell):  # new settings: its partial outputs are stale
                clear_job_outputs(cdir)
            RunDir(cdir).write_cell(cell.to_json())
    log_path = run_dir / BENCH_LOG
    launches = []
    if log_path.exists():
        with contextlib.suppress(json.JSONDecodeError):
            launches = json.loads(log_path.read_text())
    launches.append(
        {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "host": socket.gethostname(),
            "argv": argv if argv is not None else sys.argv,
            "cells": [c.key for c in cells],
        }
    )
    write_atomic(log_path, json.dumps(launches, indent=2) + "\n")
    return cells


def prepare_datasets(cells: Iterable[Cell], workers: int | None = None, progress: bool = True) -> dict[str, str]:
    """Generate (or finish) each task's dataset once, here, before the cells start.

    Without this every cell of a task would find the dataset missing and generate it at
    the same time.  Returns ``{task: error}`` for tasks whose data could not be prepared
    (their cells then fail with the full traceback in their own directory).
    """
    from d5rl.errors import UnknownTaskError
    from d5rl.registry import get_spec

    problems = {}
    cells = [c for c in cells if c.job == DEFAULT_JOB]
    for task in dict.fromkeys(c.task for c in cells):
        try:
            spec = get_spec(task)
        except (UnknownTaskError, D5RLError):
            continue  # a task only a custom job knows: nothing to generate
        if spec.dataset is None:
            continue
        try:
            from d5rl.datasets.loading import load_dataset

            # cells training on a prefix of the data (--set dataset_episodes=N) need only that prefix
            sizes = [c.overrides.get("dataset_episodes") for c in cells if c.task == task]
            episodes = None if any(n is None for n in sizes) else max(int(n) for n in sizes)
            load_dataset(task, episodes=episodes, workers=workers, progress=progress, in_memory=False)
        except Exception as e:  # noqa: BLE001 - reported, and each cell records its own failure
            problems[task] = f"{type(e).__name__}: {e}"
            print(f"warning: could not prepare the dataset of {task}: {problems[task]}", file=sys.stderr)
    return problems


def _progress(total: int, initial: int, enabled: bool):
    from d5rl.progress import progress_bar

    return progress_bar(
        total=total, initial=initial, unit="cell", desc="bench", disable=not enabled, dynamic_ncols=True
    )


def run_bench(
    cells: Iterable[Cell],
    run_dir: Path | str,
    *,
    workers: int | None = None,
    ray_address: str | None = None,
    use_ray: bool = False,
    max_attempts: int = 2,
    progress: bool = True,
    single_thread: bool = True,
    nice: int = 0,
    cpus_per_cell: float = 1.0,
    gpus_per_cell: float = 0.0,
    prepare_data: bool = True,
    argv: list[str] | None = None,
) -> BenchResult:
    """Run every unfinished cell; see the module docstring.

    ``workers=0`` runs cells one after another in this process (for debugging).
    ``use_ray`` or ``ray_address`` runs them as Ray tasks (on the cluster at
    ``ray_address``, or the Ray instance this process already initialised).
    ``prepare_data`` generates the tasks' datasets here first (cells of d5rl's trainer only).
    """
    t0 = time.time()
    run_dir = Path(run_dir)
    cells = prepare(cells, run_dir, argv)
    result = BenchResult(run_dir=run_dir)
    pending = []
    for cell in cells:
        cdir = cell.directory(run_dir)
        if RunDir(cdir).is_done():
            why = stale_reason(cell, cdir)
            if why is None:
                result.skipped.append(cell.key)
                continue
            print(f"{cell.key} is stale, training it again: {why}", file=sys.stderr)
            reset_cell(cdir)
            result.stale.append(cell.key)
        pending.append(cell)
    if prepare_data and pending:
        prepare_datasets(pending, workers=workers or None, progress=progress)
    bar = _progress(len(cells), len(result.skipped), progress)
    try:
        if use_ray or ray_address:
            _run_ray(
                pending,
                run_dir,
                result,
                bar,
                ray_address,
                max_attempts,
                single_thread,
                nice,
                cpus_per_cell,
                gpus_per_cell,
            )
        elif workers == 0:
            _run_inline(pending, run_dir, result, bar, max_attempts)
        else:
            _run_local(pending, run_dir, result, bar, workers or default_workers(), max_attempts, single_thread, nice)
    finally:
        bar.close()
    result.wall_s = time.time() - t0
    return result


def _prior_attempts(cdir: Path) -> int:
    return len(RunDir(cdir).read_failures())


def _settle(
    cell: Cell, status: str, error: str | None, result: BenchResult, bar, queue, tries: dict, max_attempts: int
) -> None:
    """Book one attempt's outcome; requeue a failure while attempts remain."""
    key = cell.key
    result.attempts[key] = tries[key]
    if status in ("ok", "skipped"):
        result.ok.append(key) if status == "ok" else result.skipped.append(key)
        result.failed.pop(key, None)
        bar.update(1)
    elif status == "busy":
        result.busy.append(key)
        bar.update(1)
    else:
        result.failed[key] = error or "unknown error"
        if tries[key] < max_attempts:
            queue.append(cell)
        else:
            bar.update(1)
    bar.set_postfix(ok=len(result.ok), failed=len(result.failed), refresh=False)


def _run_inline(pending: list[Cell], run_dir: Path, result: BenchResult, bar, max_attempts: int) -> None:
    queue = collections.deque(pending)
    tries: dict[str, int] = collections.Counter()
    while queue:
        cell = queue.popleft()
        tries[cell.key] += 1
        cdir = cell.directory(run_dir)
        out = execute_cell(cell.to_json(), str(cdir), _prior_attempts(cdir) + 1, capture_output=False)
        _settle(cell, out["status"], out.get("error"), result, bar, queue, tries, max_attempts)


def _log_tail(cdir: Path, n: int = 40) -> str:
    path = RunDir(cdir).log
    if not path.exists():
        return ""
    with contextlib.suppress(OSError):
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    return ""


def _start_worker(cell: Cell, cdir: Path, attempt: int, single_thread: bool, nice: int) -> subprocess.Popen:
    """A fresh interpreter per cell (``python -m d5rl.runner.worker``): no inherited JAX/GL state, and no
    re-import of the caller's ``__main__`` (unlike multiprocessing's spawn)."""
    payload = {
        "cell": cell.to_json(),
        "cell_dir": str(cdir),
        "attempt": attempt,
        "single_thread": single_thread,
        "nice": nice,
        "sys_path": [p for p in sys.path if p],
    }
    cdir.mkdir(parents=True, exist_ok=True)
    spec = RunDir(cdir).worker
    write_atomic(spec, json.dumps(payload))
    env = dict(os.environ)
    pkg_root = str(Path(__file__).resolve().parents[2])  # so `-m d5rl.runner.worker` finds this d5rl
    env["PYTHONPATH"] = os.pathsep.join([pkg_root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return subprocess.Popen([sys.executable, "-m", "d5rl.runner.worker", str(spec)], env=env, stdin=subprocess.DEVNULL)


def _run_local(
    pending: list[Cell],
    run_dir: Path,
    result: BenchResult,
    bar,
    workers: int,
    max_attempts: int,
    single_thread: bool,
    nice: int,
) -> None:
    queue = collections.deque(pending)
    tries: dict[str, int] = collections.Counter()
    running: list[tuple] = []
    try:
        while queue or running:
            while queue and len(running) < workers:
                cell = queue.popleft()
                tries[cell.key] += 1
                cdir = cell.directory(run_dir)
                attempt = _prior_attempts(cdir) + 1
                running.append((_start_worker(cell, cdir, attempt, single_thread, nice), cell, attempt))
            finished = [r for r in running if r[0].poll() is not None]
            if not finished:
                time.sleep(0.05)
                continue
            for item in finished:
                running.remove(item)
                proc, cell, attempt = item
                cdir = cell.directory(run_dir)
                code = proc.returncode
                if code == EXIT_CODES["ok"] and RunDir(cdir).is_done():
                    status, error = "ok", None
                elif code == EXIT_CODES["busy"]:
                    status, error = "busy", None
                elif code == EXIT_CODES["failed"]:
                    fails = RunDir(cdir).read_failures()
                    status, error = "failed", (fails[-1]["error"] if fails else f"exit code {code}")
                else:  # died before it could record anything (segfault, OOM kill, import error)
                    how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
                    error = f"worker process died ({how})"
                    record_failure(cdir, attempt, error, f"last lines of {RunDir(cdir).log.name}:\n" + _log_tail(cdir))
                    status = "failed"
                _settle(cell, status, error, result, bar, queue, tries, max_attempts)
    finally:
        for proc, _, _ in running:
            proc.terminate()
        for proc, _, _ in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)


# --------------------------------------------------------------------------- Ray


def _ray_task(cell_json: dict, cell_dir: str, attempt: int, single_thread: bool, nice: int) -> dict:
    configure_worker(single_thread, nice)
    return execute_cell(cell_json, cell_dir, attempt)


def _run_ray(
    pending: list[Cell],
    run_dir: Path,
    result: BenchResult,
    bar,
    address: str | None,
    max_attempts: int,
    single_thread: bool,
    nice: int,
    cpus: float,
    gpus: float,
) -> None:
    ray = connect_ray(address)
    # max_calls=1: a fresh worker process per cell (clean JAX state, freed memory), like the local pool;
    # retries are ours (recorded in the cell directory), so Ray's are off.
    remote = ray.remote(num_cpus=cpus, num_gpus=gpus, max_calls=1, max_retries=0)(_ray_task)
    queue = collections.deque(pending)
    tries: dict[str, int] = collections.Counter()
    running: dict = {}
    try:
        while queue or running:
            while queue:
                cell = queue.popleft()
                tries[cell.key] += 1
                cdir = cell.directory(run_dir)
                attempt = _prior_attempts(cdir) + 1
                ref = remote.remote(cell.to_json(), str(cdir.resolve()), attempt, single_thread, nice)
                running[ref] = (cell, attempt)
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                cell, attempt = running.pop(ref)
                cdir = cell.directory(run_dir)
                try:
                    out = ray.get(ref)
                    status, error = out["status"], out.get("error")
                except Exception as e:  # noqa: BLE001 - worker crash, node loss, unpicklable result
                    error = f"Ray task failed: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
                    record_failure(
                        cdir, attempt, error, f"{e}\n\nlast lines of {RunDir(cdir).log.name}:\n{_log_tail(cdir)}"
                    )
                    status = "failed"
                if status == "ok" and not RunDir(cdir).is_done():  # the cell dir is not shared with this machine
                    status, error = "failed", f"no done marker in {cdir}: is the run directory on a shared filesystem?"
                _settle(cell, status, error, result, bar, queue, tries, max_attempts)
    finally:
        for ref in running:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
