"""Run logging: one JSONL and one CSV row per logged step (TensorBoard too if installed)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

from d5rl.errors import D5RLError
from d5rl.files import read_bytes
from d5rl.training.rundir import RunDir

METRICS_MAX_BYTES = 1 << 30  # a million-step run logging every 100 steps writes ~50 MB


def read_rows(path: Path) -> list[dict]:
    """The rows of a ``metrics.jsonl`` (bounded; a damaged line is one error naming it)."""
    hint = f"delete {path} (the run's metrics restart) or train in a new --run-dir"
    rows = []
    for i, line in enumerate(read_bytes(path, METRICS_MAX_BYTES, "metrics log", hint=hint).splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except (ValueError, RecursionError):
            row = None
        if not isinstance(row, dict) or not isinstance(row.get("step"), int):
            raise D5RLError(f"{path} line {i} is not a metrics row", hint)
        rows.append(row)
    return rows


def _tb_writer(log_dir: Path):
    try:
        from tensorboardX import SummaryWriter  # type: ignore
    except ImportError:
        try:
            from torch.utils.tensorboard import SummaryWriter  # type: ignore
        except ImportError:
            return None
    try:
        return SummaryWriter(str(log_dir))
    except Exception:  # noqa: BLE001 - logging must never kill a run
        return None


class Logger:
    """Appends ``{"step": s, **metrics}`` rows to ``<run>/metrics.jsonl`` and ``<run>/metrics.csv``.

    The CSV header grows when new metric names appear (the file is rewritten).
    ``truncate_after(step)`` drops rows logged after a checkpoint when a run resumes.
    """

    def __init__(self, run_dir: str | Path, tensorboard: bool = True):
        self.dir = Path(run_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.jsonl, self.csv = RunDir(self.dir).metrics_jsonl, RunDir(self.dir).metrics_csv
        self.rows = []
        if self.jsonl.exists():
            self.rows = read_rows(self.jsonl)
        self.columns = sorted({k for r in self.rows for k in r} - {"step"})
        self.tb = _tb_writer(RunDir(self.dir).tensorboard) if tensorboard else None

    def truncate_after(self, step: int) -> None:
        self.rows = [r for r in self.rows if r["step"] <= step]
        self.jsonl.write_text("".join(json.dumps(r) + "\n" for r in self.rows))
        self._rewrite_csv()

    def _rewrite_csv(self) -> None:
        with open(self.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["step"] + self.columns)
            w.writeheader()
            for r in self.rows:
                w.writerow(r)

    def log(self, step: int, metrics: dict[str, Any]) -> None:
        row = {"step": int(step)}
        for k, v in metrics.items():
            v = float(v)
            row[k] = v if math.isfinite(v) else str(v)
        self.rows.append(row)
        with open(self.jsonl, "a") as f:
            f.write(json.dumps(row) + "\n")
        new = sorted(set(row) - {"step"} - set(self.columns))
        if new:
            self.columns = sorted(set(self.columns) | set(new))
            self._rewrite_csv()
        else:
            with open(self.csv, "a", newline="") as f:
                csv.DictWriter(f, fieldnames=["step"] + self.columns).writerow(row)
        if self.tb is not None:
            for k, v in row.items():
                if k != "step" and isinstance(v, float):
                    self.tb.add_scalar(k, v, step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()
