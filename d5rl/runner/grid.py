"""The benchmark grid: cells (task × algorithm × seed), their directories and tuned settings.

A grid's directory holds one run directory per cell, at ``<task>/<algo>/seed<k>/``, and the log of the grid's
launches (the files of both: :mod:`d5rl.training.rundir`).

A cell records only what the user chose (``--set`` values, protocol flags, ``tuned``); :meth:`Cell.spec`
resolves everything else with :func:`d5rl.settings.resolve`, exactly as ``d5rl train`` does for the same
task and algorithm.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterable
from pathlib import Path

from d5rl.agents import canonical_name as canonical_algo
from d5rl.agents import get_agent
from d5rl.datasets.generation import stale_data
from d5rl.errors import D5RLError
from d5rl.files import read_json
from d5rl.settings import resolve, run_steps
from d5rl.training.config import EXECUTION_KEYS, RunSpec
from d5rl.training.rundir import CELL, RunDir

DEFAULT_JOB = "d5rl.runner.jobs:train_job"


class GridError(D5RLError, ValueError):
    """A grid that cannot run: unknown algorithm, clash with finished cells, bad tuned file."""


@dataclasses.dataclass(frozen=True)
class Cell:
    """One training run of the grid."""

    task: str
    algo: str
    seed: int
    offline_steps: int
    online_steps: int
    overrides: dict = dataclasses.field(default_factory=dict)  # the user's --set values (agent or loop keys)
    protocol: dict = dataclasses.field(default_factory=dict)  # the user's evaluation flags (interval, episodes)
    job: str = DEFAULT_JOB  # "module:function" called as job(cell, cell_dir)
    tuned: bool = True  # layer d5rl/configs/settings.json under the overrides (False: agent defaults)

    @property
    def key(self) -> str:
        return f"{self.task}/{self.algo}/seed{self.seed}"

    def directory(self, run_dir: Path | str) -> Path:
        return Path(run_dir) / self.task / self.algo / f"seed{self.seed}"

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    def spec(self) -> RunSpec:
        """The run spec d5rl's trainer runs this cell with: the settings file (unless ``tuned`` is off) under the
        cell's protocol flags and ``--set`` values, with the progress bar off (the grid shows its own)."""
        return resolve(
            self.algo,
            self.task,
            {"progress": False, **self.protocol, **self.overrides},
            offline_steps=self.offline_steps,
            online_steps=self.online_steps,
            seed=self.seed,
            tuned=self.tuned,
        )

    @classmethod
    def from_json(cls, d: dict) -> Cell:
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in fields})


def same_run(a: Cell, b: Cell) -> bool:
    """Whether two cells compute the same thing: equal but for ``--set`` values of the trainer's
    execution-only settings (:data:`d5rl.training.config.EXECUTION_KEYS`: checkpoints, RAM,
    evaluation envs and processes, progress)."""

    def what(c: Cell) -> dict:
        return {**c.to_json(), "overrides": {k: v for k, v in c.overrides.items() if k not in EXECUTION_KEYS}}

    return what(a) == what(b)


def parse_assignments(items: Iterable[str] | None) -> dict[str, str]:
    """``["expectile=0.9"]`` -> ``{"expectile": "0.9"}``: the text is kept; the trainer parses it as the type
    of the setting's default (:meth:`d5rl.agents.config.Config.override`, the one parser)."""
    out: dict[str, str] = {}
    for item in items or ():
        if "=" not in item:
            raise GridError(f"override {item!r} is not key=value", "write e.g. --set expectile=0.9")
        key, text = item.split("=", 1)
        out[key.strip()] = text
    return out


def expand_grid(
    tasks: Iterable[str],
    algos: Iterable[str],
    seeds: Iterable[int],
    offline_steps: int,
    online_steps: int,
    overrides: dict | None = None,
    job: str = DEFAULT_JOB,
    tuned: bool = True,
    protocol_overrides: dict | None = None,
) -> list[Cell]:
    """All cells of the grid.  With d5rl's trainer, agents without an offline phase (RLPD) take no
    offline steps in an offline-to-online grid (their online batches mix in the offline data)."""
    cells = []
    for task, algo, seed in itertools.product(list(tasks), list(algos), list(seeds)):
        algo = canonical_algo(algo)
        offline, online = int(offline_steps), int(online_steps)
        if job == DEFAULT_JOB:
            offline, online = run_steps(algo, offline, online)
        cells.append(
            Cell(
                task=task,
                algo=algo,
                seed=int(seed),
                offline_steps=offline,
                online_steps=online,
                overrides=dict(overrides or {}),
                protocol=dict(protocol_overrides or {}),
                job=job,
                tuned=bool(tuned),
            )
        )
    keys = [c.key for c in cells]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise GridError(f"grid lists cells twice: {sorted(dup)}", "remove repeated tasks, algorithms or seeds")
    return cells


def read_cell(cell_dir: Path) -> Cell | None:
    path = RunDir(cell_dir).cell
    if not path.exists():
        return None
    return Cell.from_json(
        read_json(
            path, "cell file", error=GridError, hint=f"delete {cell_dir} and run the grid again (the cell starts over)"
        )
    )


def find_cells(run_dir: Path | str) -> list[tuple[Cell, Path]]:
    """Every cell directory under ``run_dir`` (those with a ``cell.json``), sorted by key."""
    out = []
    for path in sorted(Path(run_dir).glob(f"*/*/seed*/{CELL}")):
        cell = read_cell(path.parent)
        if cell is not None:
            out.append((cell, path.parent))
    return out


def trained_on(cell_dir: Path) -> dict | None:
    """The dataset a cell's job recorded in its config.json (d5rl's trainer does), or None."""
    record = (RunDir(cell_dir).read_config_leniently() or {}).get("dataset")
    return record if isinstance(record, dict) else None


def stale_reason(cell: Cell, cell_dir: Path) -> str | None:
    """Why a cell's result no longer describes what the same command would train, or None (current, or
    nothing recorded to tell): its task's data changed (dataset or generator version), or, for d5rl's
    trainer, its agent's code (:attr:`d5rl.agents.common.Agent.version`) or the settings it resolves to."""
    return stale_data(cell.task, trained_on(cell_dir)) or stale_agent(cell, cell_dir)


# Loop settings that change what a run learns (the others change how it is evaluated, logged or executed).
LEARNING_KEYS = ("frame_stack", "offline_ratio", "start_steps", "buffer_capacity", "dataset_episodes")


def stale_agent(cell: Cell, cell_dir: Path) -> str | None:
    """Why a cell d5rl's trainer ran was trained by another agent than the one its command gives now: an older
    version of the agent's code, or other resolved settings (a value in ``d5rl/configs/settings.json`` or an
    agent default changed), compared with its ``config.json``; None when they agree or nothing was recorded."""
    if cell.job != DEFAULT_JOB:
        return None
    record = RunDir(cell_dir).read_config_leniently()
    if record is None or not isinstance(record.get("agent"), dict):
        return None
    try:
        now = get_agent(cell.algo)[0].version
        resolved = cell.spec()
    except D5RLError:  # a task or algorithm this code no longer has: nothing to compare with
        return None
    was = record.get("agent_version", 1)
    if was != now:
        return f"trained with {cell.algo} v{was}; d5rl's {cell.algo} is now v{now}"
    agent, train = resolved.agent.to_dict(), resolved.train.to_dict()
    old_agent, old_train = record["agent"], record.get("train") or {}
    # Compared: the keys both have.  Values the trainer fills from the data (None here: observation statistics,
    # action size) are not settings; a key added since the cell ran keeps the old behaviour as its default (a
    # change of behaviour bumps the agent's version).
    diffs = [k for k in sorted(agent) if k in old_agent and agent[k] is not None and agent[k] != old_agent[k]]
    diffs += [k for k in LEARNING_KEYS if k in old_train and old_train[k] != train.get(k)]
    if not diffs:
        return None
    both = {**old_train, **old_agent}
    now_all = {**train, **agent}
    return "trained with other settings: " + ", ".join(f"{k} {both.get(k)!r} -> {now_all.get(k)!r}" for k in diffs)
