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
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from d5rl.datasets.loading import load_dataset
from d5rl.errors import D5RLError, UnknownTaskError
from d5rl.files import write_atomic
from d5rl.parallel import Executor, Ray
from d5rl.progress import progress_bar
from d5rl.registry import get_spec
from d5rl.runner.execute import clear_job_outputs, record_failure, reset_cell
from d5rl.runner.grid import DEFAULT_JOB, Cell, GridError, read_cell, same_run, stale_reason
from d5rl.training.rundir import BENCH_LOG, RunDir

EXECUTE = "d5rl.runner.execute:execute_cell"  # what every cell runs, in a worker process of its own


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
            # cells training on a prefix of the data (--set dataset_episodes=N) need only that prefix
            sizes = [c.overrides.get("dataset_episodes") for c in cells if c.task == task]
            episodes = None if any(n is None for n in sizes) else max(int(n) for n in sizes)
            load_dataset(task, episodes=episodes, workers=workers, progress=progress, in_memory=False)
        except Exception as e:  # noqa: BLE001 - reported, and each cell records its own failure
            problems[task] = f"{type(e).__name__}: {e}"
            print(f"warning: could not prepare the dataset of {task}: {problems[task]}", file=sys.stderr)
    return problems


def _progress(total: int, initial: int, enabled: bool):
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
    if use_ray or ray_address:
        backend = Ray(ray_address)
    else:
        backend = 0 if workers == 0 else workers or default_workers()
    try:
        with Executor(
            backend, fresh=True, single_thread=single_thread, nice=nice, cpus=cpus_per_cell, gpus=gpus_per_cell
        ) as tasks:
            _run(pending, run_dir, result, bar, tasks, max_attempts, capture_output=backend != 0)
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


def _run(
    pending: list[Cell], run_dir: Path, result: BenchResult, bar, tasks: Executor, max_attempts: int, capture_output
):
    """Run the cells through ``tasks`` (one :func:`~d5rl.runner.execute.execute_cell` each), retrying a failed
    cell while it has attempts left; a worker that died before recording anything is recorded here."""
    queue = collections.deque(pending)
    tries: dict[str, int] = collections.Counter()
    cells: dict[str, tuple[Cell, int]] = {}
    while queue or tasks.running:
        while queue and tasks.free:
            cell = queue.popleft()
            tries[cell.key] += 1
            cdir = cell.directory(run_dir)
            attempt = _prior_attempts(cdir) + 1
            cells[str(cdir)] = (cell, attempt)
            cdir.mkdir(parents=True, exist_ok=True)
            tasks.submit(str(cdir), EXECUTE, cell.to_json(), str(cdir.resolve()), attempt, capture_output)
        for done in tasks.wait():
            cell, attempt = cells.pop(done.key)
            cdir = Path(done.key)
            if done.error is not None:  # died before it could record anything (segfault, OOM kill, lost node)
                tail = f"last lines of {RunDir(cdir).log.name}:\n{_log_tail(cdir)}"
                record_failure(cdir, attempt, done.error, f"{done.traceback}\n\n{tail}".lstrip())
                status, error = "failed", done.error
            else:
                status, error = done.value["status"], done.value.get("error")
            if status == "ok" and not RunDir(cdir).is_done():  # the cell dir is not shared with this machine
                status, error = "failed", f"no done marker in {cdir}: is the run directory on a shared filesystem?"
            _settle(cell, status, error, result, bar, queue, tries, max_attempts)


def _log_tail(cdir: Path, n: int = 40) -> str:
    path = RunDir(cdir).log
    if not path.exists():
        return ""
    with contextlib.suppress(OSError):
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    return ""
