"""The benchmark grid: cells (task × algorithm × seed), their directories and tuned settings.

A run directory holds one directory per cell::

    RUN_DIR/
      bench.json                      # the grids launched into this directory (appended)
      <task>/<algo>/seed<k>/
        cell.json                     # what this cell runs (task, algo, seed, steps, overrides, job)
        done                          # written atomically after success (JSON summary)
        failures.jsonl                # one line per failed attempt: error + traceback
        error.txt                     # traceback of the latest failure
        log.txt                       # the job's stdout/stderr
        ...                           # whatever the trainer writes (config, eval logs, checkpoints)

Settings per cell come from three layers: the agent's defaults, the tuned values
for its (algorithm, task family) in ``d5rl/configs/tuned.json``, and the user's
``--set key=value`` overrides (highest priority).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
from pathlib import Path
from typing import Any, Iterable

from d5rl.errors import D5RLError

TUNED_PATH = Path(__file__).resolve().parent.parent / "configs" / "tuned.json"
DEFAULT_JOB = "d5rl.runner.jobs:train_job"
CELL_FILE = "cell.json"
DONE_FILE = "done"
FAILURES_FILE = "failures.jsonl"
ERROR_FILE = "error.txt"
LOG_FILE = "log.txt"
LOCK_FILE = ".lock"
WORKER_FILE = ".worker.json"
# Files the runner owns in a cell directory; everything else belongs to the job
# and is cleared before a fresh attempt (a half-written eval log must not mix
# with the next attempt's).
RUNNER_FILES = frozenset({CELL_FILE, DONE_FILE, FAILURES_FILE, ERROR_FILE, LOG_FILE, LOCK_FILE, WORKER_FILE})


class GridError(D5RLError, ValueError):
    """A grid that cannot run: unknown algorithm, clash with finished cells, bad tuned file."""


def canonical_algo(name: str) -> str:
    """``TD3+BC`` → ``td3bc``, ``ddpm-bc`` → ``ddpm_bc`` (the names of :data:`d5rl.agents.AGENTS`)."""
    key = name.strip().lower().replace("-", "_").replace("+", "")
    return {"td3_bc": "td3bc", "ddpmbc": "ddpm_bc", "cal_ql": "calql"}.get(key, key)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One training run of the grid."""

    task: str
    algo: str
    seed: int
    offline_steps: int
    online_steps: int
    overrides: dict = dataclasses.field(default_factory=dict)  # agent-config values (tuned + --set)
    protocol: dict = dataclasses.field(default_factory=dict)  # trainer settings (eval interval, episodes)
    job: str = DEFAULT_JOB  # "module:function" called as job(cell, cell_dir)

    @property
    def key(self) -> str:
        return f"{self.task}/{self.algo}/seed{self.seed}"

    def directory(self, run_dir: Path | str) -> Path:
        return Path(run_dir) / self.task / self.algo / f"seed{self.seed}"

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "Cell":
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in fields})


# --------------------------------------------------------------------------- tuned settings


@functools.lru_cache(maxsize=4)
def _load_tuned(path: str) -> dict:
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError as e:
        raise GridError(f"tuned-settings file {path} not found", "reinstall d5rl or pass --tuned PATH") from e
    except json.JSONDecodeError as e:
        raise GridError(f"tuned-settings file {path} is not valid JSON ({e})", "fix the file") from e
    for section in ("tuned", "protocol"):
        if not isinstance(data.get(section), dict):
            raise GridError(f"{path} has no '{section}' table", "see d5rl/configs/tuned.json for the layout")
    return data


def family_key(task_id: str, table: dict) -> str | None:
    """The longest key of ``table`` that is ``task_id`` or a dash-separated prefix of it."""
    best = None
    for key in table:
        if key.startswith("_"):
            continue
        if task_id == key or task_id.startswith(key + "-"):
            if best is None or len(key) > len(best):
                best = key
    return best


def tuned_settings(task_id: str, algo: str, path: Path | str | None = None) -> tuple[dict, dict]:
    """``(agent overrides, trainer protocol)`` for a task and algorithm from the tuned file."""
    data = _load_tuned(str(path or TUNED_PATH))
    algo = canonical_algo(algo)
    fam = family_key(task_id, data["tuned"])
    overrides = {}
    if fam is not None:
        overrides = {k: v for k, v in data["tuned"][fam].get(algo, {}).items() if not k.startswith("_")}
    pfam = family_key(task_id, data["protocol"])
    protocol = {}
    if pfam is not None:
        protocol = {k: v for k, v in data["protocol"][pfam].items() if not k.startswith("_")}
    return overrides, protocol


def parse_assignments(items: Iterable[str] | None) -> dict[str, Any]:
    """``["expectile=0.9", "hidden_dims=[512,512]"]`` → values parsed as JSON where possible."""
    out: dict[str, Any] = {}
    for item in items or ():
        if "=" not in item:
            raise GridError(f"override {item!r} is not key=value", "write e.g. --set expectile=0.9")
        key, text = item.split("=", 1)
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        out[key.strip()] = value
    return out


def expand_grid(tasks: Iterable[str], algos: Iterable[str], seeds: Iterable[int], offline_steps: int,
                online_steps: int, overrides: dict | None = None, job: str = DEFAULT_JOB,
                tuned: Path | str | None | bool = None, protocol_overrides: dict | None = None) -> list[Cell]:
    """All cells of the grid, tuned settings applied (``tuned=False`` skips the tuned file)."""
    cells = []
    for task, algo, seed in itertools.product(list(tasks), list(algos), list(seeds)):
        algo = canonical_algo(algo)
        if tuned is False:
            tuned_over, protocol = {}, {}
        else:
            tuned_over, protocol = tuned_settings(task, algo, tuned or None)
        cells.append(Cell(
            task=task, algo=algo, seed=int(seed), offline_steps=int(offline_steps),
            online_steps=int(online_steps), overrides={**tuned_over, **(overrides or {})},
            protocol={**protocol, **(protocol_overrides or {})}, job=job,
        ))
    keys = [c.key for c in cells]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise GridError(f"grid lists cells twice: {sorted(dup)}", "remove repeated tasks, algorithms or seeds")
    return cells


def read_cell(cell_dir: Path) -> Cell | None:
    path = Path(cell_dir) / CELL_FILE
    if not path.exists():
        return None
    with open(path) as f:
        return Cell.from_json(json.load(f))


def find_cells(run_dir: Path | str) -> list[tuple[Cell, Path]]:
    """Every cell directory under ``run_dir`` (those with a ``cell.json``), sorted by key."""
    out = []
    for path in sorted(Path(run_dir).glob(f"*/*/seed*/{CELL_FILE}")):
        cell = read_cell(path.parent)
        if cell is not None:
            out.append((cell, path.parent))
    return out
