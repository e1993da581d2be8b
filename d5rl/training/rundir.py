"""A run directory: every file a training run or a grid cell keeps, named here and read and written here.

``d5rl train --run-dir DIR`` writes a run directory; each cell of a ``d5rl bench`` grid is one, to which the
grid's runner adds its own files::

    DIR/
      config.json          the run spec, the agent's settings as fitted to the data, the agent's version and the
                           dataset (written before training; ``d5rl eval`` and reports read it)
      checkpoint/          the latest checkpoint (its files: d5rl.training.checkpoint); checkpoint.prev/ the one
                           before; .checkpoint.tmp-<pid>/ one being written
      metrics.jsonl        one row per log or evaluation step; metrics.csv the same rows; tb/ TensorBoard events
      eval_progress.json   the finished episodes of an unfinished evaluation
      summary.json         the final evaluation: means and each episode's return, length and score
      videos/              evaluation videos (``save_video=True``)
      .train.lock          held by the process training into the directory
    written by the grid's runner (d5rl.runner):
      cell.json            what the cell runs (task, algorithm, seed, steps, overrides, job)
      done                 written atomically after success (JSON: attempt, wall time, host, the job's summary)
      failures.jsonl       one line per failed attempt (error and traceback); error.txt the latest
      log.txt              the job's stdout and stderr, every attempt
      .lock, .worker.json  held by the process running the cell; what a worker process was started with

A grid's directory holds the cells at ``<task>/<algo>/seed<k>/`` and its log of launches, ``bench.json``.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

from d5rl.errors import D5RLError, is_int
from d5rl.files import json_type_error, read_bytes, read_json, write_atomic

# What a run's trainer writes
CONFIG = "config.json"
CHECKPOINT = "checkpoint"
PREVIOUS_CHECKPOINT = "checkpoint.prev"
CHECKPOINT_TMP_PREFIX = ".checkpoint.tmp-"
METRICS_JSONL = "metrics.jsonl"
METRICS_CSV = "metrics.csv"
TENSORBOARD = "tb"
EVAL_PROGRESS = "eval_progress.json"
SUMMARY = "summary.json"
VIDEOS = "videos"
TRAIN_LOCK = ".train.lock"
# What the grid's runner writes into a cell's directory
CELL = "cell.json"
DONE = "done"
FAILURES = "failures.jsonl"
ERROR = "error.txt"
LOG = "log.txt"
CELL_LOCK = ".lock"
WORKER = ".worker.json"
RUNNER_FILES = frozenset({CELL, DONE, FAILURES, ERROR, LOG, CELL_LOCK, WORKER})  # kept when a job starts over
# Where a report reads a cell's evaluations, first found first: another job's eval.csv / eval.jsonl, or the
# rows of d5rl's trainer (the contract: d5rl.runner.logs)
EVAL_FILES = ("eval.csv", "eval.jsonl", METRICS_JSONL, METRICS_CSV)
# Never worth copying out of a cell (archives): locks, the checkpoint before the latest, TensorBoard copies
NOT_ARCHIVED = (PREVIOUS_CHECKPOINT, CELL_LOCK, TRAIN_LOCK, WORKER, TENSORBOARD)
# In a grid's directory: one line per launch of the grid
BENCH_LOG = "bench.json"

FAILURES_MAX_BYTES = 64 << 20  # a record is a few kB (its traceback); a cell fails a handful of times
CONFIG_HINT = "pass the directory a `d5rl train` run wrote, or train again in a new --run-dir"


class RunDirError(D5RLError):
    """A run directory that holds a different run, or whose files cannot be read."""


class RunDir:
    """The files of one run directory (see the module docstring)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    # --- paths -----------------------------------------------------------------------------------------------
    config = property(lambda self: self.path / CONFIG)
    checkpoint = property(lambda self: self.path / CHECKPOINT)
    previous_checkpoint = property(lambda self: self.path / PREVIOUS_CHECKPOINT)
    metrics_jsonl = property(lambda self: self.path / METRICS_JSONL)
    metrics_csv = property(lambda self: self.path / METRICS_CSV)
    tensorboard = property(lambda self: self.path / TENSORBOARD)
    eval_progress = property(lambda self: self.path / EVAL_PROGRESS)
    summary = property(lambda self: self.path / SUMMARY)
    videos = property(lambda self: self.path / VIDEOS)
    train_lock = property(lambda self: self.path / TRAIN_LOCK)
    cell = property(lambda self: self.path / CELL)
    done = property(lambda self: self.path / DONE)
    failures = property(lambda self: self.path / FAILURES)
    error = property(lambda self: self.path / ERROR)
    log = property(lambda self: self.path / LOG)
    cell_lock = property(lambda self: self.path / CELL_LOCK)
    worker = property(lambda self: self.path / WORKER)

    def checkpoint_tmp(self, pid: int) -> Path:
        return self.path / f"{CHECKPOINT_TMP_PREFIX}{pid}"

    def video(self, step: int) -> Path:
        """The video of the evaluation at ``step``."""
        return self.videos / f"step{step:09d}.mp4"

    def eval_file(self) -> Path | None:
        """The file a report reads this cell's evaluations from (:data:`EVAL_FILES`), if any."""
        return next((p for p in (self.path / name for name in EVAL_FILES) if p.exists()), None)

    # --- config.json -----------------------------------------------------------------------------------------
    def read_config(self) -> dict:
        """``config.json`` with the fields a resumed run and ``d5rl eval`` use, type-checked (one line if not)."""
        path = self.config
        if not path.exists():
            raise RunDirError(f"{self.path} has no {CONFIG}", "pass the directory a `d5rl train` run wrote")
        cfg = read_json(path, "run config", error=RunDirError, hint=CONFIG_HINT)
        checks = (
            ("algo", lambda v: isinstance(v, str), "an algorithm name"),
            ("task_id", lambda v: isinstance(v, str), "a task id"),
            ("seed", lambda v: is_int(v, lo=0), "a non-negative integer"),
            ("agent", lambda v: isinstance(v, dict), "an object of agent settings"),
            (
                "train",
                lambda v: isinstance(v, dict) and is_int(v.get("frame_stack"), lo=1),
                "an object of training settings with frame_stack",
            ),
        )
        if not isinstance(cfg, dict):
            raise json_type_error("run config", path, "the file", cfg, "a JSON object", RunDirError, CONFIG_HINT)
        for key, ok, expected in checks:
            if not ok(cfg.get(key)):
                raise json_type_error("run config", path, key, cfg.get(key), expected, RunDirError, CONFIG_HINT)
        return cfg

    def read_config_leniently(self) -> dict | None:
        """``config.json`` as written, or None when it is missing or not a JSON object (a grid's other jobs)."""
        try:
            record = json.loads(self.config.read_text())
        except (OSError, ValueError):
            return None
        return record if isinstance(record, dict) else None

    def write_config(self, record: dict) -> None:
        self.config.write_text(json.dumps(record, indent=2) + "\n")

    # --- summary.json ----------------------------------------------------------------------------------------
    def read_summary(self) -> dict | None:
        """The final evaluation, or None when there is none (or it cannot be read)."""
        try:
            summary = read_json(self.summary, "run summary", error=RunDirError)
        except (FileNotFoundError, RunDirError):
            return None
        return summary if isinstance(summary, dict) else None

    def write_summary(self, summary: dict) -> None:
        self.summary.write_text(json.dumps(summary, indent=2) + "\n")

    # --- the grid runner's files -----------------------------------------------------------------------------
    def is_done(self) -> bool:
        return self.done.exists()

    def write_done(self, record: dict) -> None:
        write_atomic(self.done, json.dumps(record, indent=2, default=str) + "\n")

    def write_cell(self, cell: dict) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        write_atomic(self.cell, json.dumps(cell, indent=2, sort_keys=True) + "\n")

    def read_failures(self) -> list[dict]:
        """The failed attempts' records (a damaged line is left out)."""
        if not self.failures.exists():
            return []
        out = []
        text = read_bytes(self.failures, FAILURES_MAX_BYTES, "failure log").decode(errors="replace")
        for line in text.splitlines():
            if line.strip():
                with contextlib.suppress(json.JSONDecodeError):
                    out.append(json.loads(line))
        return out

    def add_failure(self, record: dict, text: str) -> None:
        """Append a failed attempt's record to ``failures.jsonl``; ``error.txt`` becomes ``text``."""
        with open(self.failures, "a") as f:
            f.write(json.dumps(record) + "\n")
        write_atomic(self.error, text)
