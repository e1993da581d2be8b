"""The results of a grid: its cells read from their run directories (scores, staleness, wall time, what the
agents did), the tables of final normalized scores built from them, and their aggregates.

The renderers (:mod:`d5rl.runner.tables`, :mod:`d5rl.runner.plots`, :mod:`d5rl.runner.videos`) and the report
page (:mod:`d5rl.runner.report`) read these; nothing here writes a file.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from d5rl.errors import D5RLError
from d5rl.runner import stats
from d5rl.runner.execute import attempt_header
from d5rl.runner.grid import find_cells, stale_reason, trained_on
from d5rl.runner.logs import final_scores, read_evals
from d5rl.settings import task_keys
from d5rl.training.rundir import RunDir

# Paper order and display names; algorithms outside this list follow in alphabetical order.
METHODS = {
    "bc": "BC",
    "iql": "IQL",
    "cql": "CQL",
    "calql": "CalQL",
    "td3bc": "TD3+BC",
    "rlpd": "RLPD",
    "ddpm_bc": "DDPM+BC",
    "idql": "IDQL",
    "fql": "FQL",
    "rebrac": "ReBRAC",
}


# (benchmark group, environment label) in the paper's row order.
ENVIRONMENTS = [
    ("kitchen-standard", "Standard Kitchen"),
    ("kitchen-randomized", "Randomized Kitchen"),
    ("a1", "Locomotion"),
    ("wx", "WidowX"),
]


VIDEO_EXTS = (".mp4", ".gif", ".webm")


VIDEOS_PER_CELL = 3


GRID_FOLDER = "cells"  # a published grid's cells live in docs/results/NAME/cells: the grid's name is NAME


class ReportError(D5RLError):
    """Nothing to report (no cells, or no finished cell with evaluations)."""


def environment(task: str) -> str:
    """The table's environment label of a task: its benchmark group (TaskSpec.group)."""
    try:
        group, _ = task_keys(task)
    except D5RLError:  # a task only a custom job knows
        group = task.split("-")[0]
    return dict(ENVIRONMENTS).get(group, group)


def _env_order(label: str) -> int:
    labels = [lab for _, lab in ENVIRONMENTS]
    return labels.index(label) if label in labels else len(labels)


def task_order(task: str) -> tuple:
    """Sort key of a task in the tables: the paper's environment order, then the task id."""
    env = environment(task)
    return _env_order(env), env, task


def method_name(algo: str) -> str:
    return METHODS.get(algo, algo)


def method_order(algos) -> list[str]:
    known = [a for a in METHODS if a in algos]
    return known + sorted(a for a in algos if a not in METHODS)


@dataclasses.dataclass
class CellResult:
    task: str
    algo: str
    seed: int
    offline_steps: int
    online_steps: int
    directory: Path
    done: bool
    evals: list[dict]
    final: dict[str, float]
    failures: int
    videos: list[Path]
    stale: str | None = None  # why the result describes data the task no longer has (None: current)
    data: dict | None = None  # the dataset the job recorded (name, versions, seed, episodes)
    wall_s: float | None = None  # the run's wall time summed over the processes that ran it (a resumed run has several)
    wall_is_last_process: bool = False  # resumed by code that did not yet add up earlier processes: a lower bound
    eval_episodes: int | None = None  # episodes of the final evaluation
    stats: dict[str, float] | None = None  # the final evaluation's episode statistics (what the agent did)

    @property
    def counts(self) -> bool:
        """Finished on the task's current data: its scores go into the tables."""
        return self.done and self.stale is None

    @property
    def final_step(self) -> dict[str, int]:
        """The step of each phase's last evaluation."""
        out = {}
        for e in self.evals:
            out[e["phase"]] = e["step"]
        return out


def collect(run_dir: Path | str) -> list[CellResult]:
    """Every cell of a run directory with its evaluations (read from the cell's eval log)."""
    out = []
    for cell, cdir in find_cells(run_dir):
        rows = read_evals(cdir, cell.task, cell.offline_steps)
        final = final_scores(rows)
        if cell.online_steps <= 0:
            final.pop("online", None)
        videos = sorted(p for p in cdir.rglob("*") if p.suffix.lower() in VIDEO_EXTS)
        files = RunDir(cdir)
        done = files.is_done()
        marker = _read_json(files.done) if done else {}
        summary = marker.get("summary") or {}
        wall, partial = summary.get("run_wall_s"), False
        if wall is None and marker.get("wall_s") is not None:  # older runs: the last process's time only
            wall, partial = marker["wall_s"], _processes(files.log, cell.key) > 1
        out.append(
            CellResult(
                cell.task,
                cell.algo,
                cell.seed,
                cell.offline_steps,
                cell.online_steps,
                cdir,
                done,
                rows,
                final,
                len(files.read_failures()),
                videos,
                stale=stale_reason(cell, cdir) if done else None,
                data=trained_on(cdir),
                wall_s=wall,
                wall_is_last_process=partial,
                eval_episodes=summary.get("episodes"),
                stats=_read_json(files.summary).get("stats") if done else None,
            )
        )
    return out


def _processes(log: Path, key: str) -> int:
    """How many processes worked on a cell: the attempt headers in its log."""
    try:
        return sum(line.startswith(attempt_header(key)) for line in log.read_text(errors="replace").splitlines())
    except OSError:
        return 1


def _read_json(path: Path) -> dict:
    try:
        out = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return out if isinstance(out, dict) else {}


def table_cells(results: list[CellResult], phase: str) -> dict[tuple[str, str], list[CellResult]]:
    """``{(task, algo): cells}``: the finished cells on current data with a final score in ``phase``, the
    cells behind each entry of that phase's table."""
    out: dict[tuple[str, str], list[CellResult]] = {}
    for r in results:
        if r.counts and phase in r.final:
            out.setdefault((r.task, r.algo), []).append(r)
    return out


def score_table(results: list[CellResult], phase: str) -> dict[tuple[str, str], np.ndarray]:
    """``{(task, algo): final scores over seeds}`` of finished cells for one phase."""
    return {
        k: np.asarray([r.final[phase] for r in cells], np.float64) for k, cells in table_cells(results, phase).items()
    }


def seed_interval(scores, reps: int = 2000, seed: int = 0, confidence: float = 0.95) -> tuple[float, float]:
    """The percentile-bootstrap interval of the mean score over seeds (one stratum of
    :func:`d5rl.runner.stats.stratified_bootstrap_ci`); with one seed, that seed's score twice."""
    _, lo, hi = stats.stratified_bootstrap_ci(
        [np.asarray(scores, np.float64)], np.mean, reps=reps, confidence=confidence, rng=np.random.default_rng(seed)
    )
    return lo, hi


def aggregate(table: dict, reps: int = 2000, seed: int = 0) -> list[dict]:
    """Per method (overall and per environment): IQM with a 95 % stratified-bootstrap CI, and the mean."""
    out = []
    algos = method_order({a for _, a in table})
    envs = sorted({environment(t) for t, _ in table}, key=lambda e: (_env_order(e), e))
    for a in algos:
        groups = [("all", None)] + [(e, e) for e in envs] if len(envs) > 1 else [("all", None)]
        for label, env in groups:
            strata = [v for (t, aa), v in sorted(table.items()) if aa == a and (env is None or environment(t) == env)]
            if not strata:
                continue
            rng = np.random.default_rng(seed)
            point, lo, hi = stats.stratified_bootstrap_ci(strata, stats.iqm, reps=reps, rng=rng)
            pooled = np.concatenate(strata)
            out.append(
                {
                    "method": a,
                    "group": label,
                    "tasks": len(strata),
                    "runs": int(pooled.size),
                    "iqm": point,
                    "iqm_lo": lo,
                    "iqm_hi": hi,
                    "mean": float(pooled.mean()),
                }
            )
    return out


def behaviour_table(results: list[CellResult]) -> list[dict]:
    """What the agents did in their final evaluation, from the statistics their task reports per episode (the
    kitchen: which subtasks were done; WidowX: each object lifted, in its bin, in the other; A1: speed, falls):
    per task (paper order) a row per method with the mean of each statistic over the finished cells that
    recorded it (None where none did)."""
    groups: dict[str, dict[str, list[dict]]] = {}
    for r in results:
        if r.counts and r.stats:
            groups.setdefault(r.task, {}).setdefault(r.algo, []).append(r.stats)
    out = []
    for task in sorted(groups, key=task_order):
        by_algo = groups[task]
        keys = sorted(set().union(*(st for cells in by_algo.values() for st in cells)))
        rows = []
        for algo in method_order(by_algo):
            vals = {k: [st[k] for st in by_algo[algo] if k in st] for k in keys}
            rows.append(
                {
                    "algo": algo,
                    "method": method_name(algo),
                    "cells": len(by_algo[algo]),
                    "stats": {k: float(np.mean(v)) if v else None for k, v in vals.items()},
                }
            )
        out.append(
            {
                "task": task,
                "keys": keys,
                "labels": [k.removeprefix("subtask/").replace("_", " ") for k in keys],
                "rows": rows,
            }
        )
    return out


def mean_curves(cells: list[CellResult]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per algorithm (paper order), over the cells' seeds: ``(steps, mean score, std score)`` at every
    evaluated step.  ``cells`` should be of one task."""
    out = {}
    for a in method_order({c.algo for c in cells}):
        per_step: dict[int, list[float]] = {}
        for c in cells:
            if c.algo != a:
                continue
            for e in c.evals:
                per_step.setdefault(e["step"], []).append(e["score"])
        steps = np.array(sorted(per_step))
        out[a] = (
            steps,
            np.array([np.mean(per_step[s]) for s in steps]),
            np.array([np.std(per_step[s]) for s in steps]),
        )
    return out
