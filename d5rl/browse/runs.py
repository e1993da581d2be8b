"""``d5rl bench`` run directories for the browse page: read with :func:`d5rl.runner.results.collect` (the
report's own reader), summarized as per-task comparison tables (with the paper's values), learning curves,
final scores per seed, what the agents did and rollout videos."""

from __future__ import annotations

import os
from pathlib import Path

from d5rl.browse.catalog import json_floats
from d5rl.runner import results as grid
from d5rl.runner import tables as render
from d5rl.runner.paper import paper_repeats, paper_result, paper_task, repeat_text


def run_labels(run_dirs: list[Path]) -> list[str]:
    """A name for each run directory that tells it from the others: its path relative to the directories'
    common parent.  A label that would be the bare grid folder (``cells``) keeps the folder above it, so
    ``docs/results/table1-state/cells`` alone is ``table1-state/cells``; a directory given twice gets
    ``#2``, ``#3``... after its label."""
    dirs = [Path(os.path.abspath(r)) for r in run_dirs]
    if not dirs:
        return []
    base = Path(os.path.commonpath([d.parent for d in dirs]))
    labels = [os.path.relpath(d, base) for d in dirs]
    if grid.GRID_FOLDER in labels and base.parent != base:
        labels = [os.path.relpath(d, base.parent) for d in dirs]
    seen: dict[str, int] = {}
    out = []
    for lab in labels:
        seen[lab] = seen.get(lab, 0) + 1
        out.append(lab if seen[lab] == 1 else f"{lab} #{seen[lab]}")
    return out


def comparison_rows(results: list[grid.CellResult], phase: str) -> list[dict]:
    """One row per (task, algorithm) of the phase's table, in the report's order: the seeds' final scores,
    their mean ± std (as the report writes them), the bootstrap interval of the mean
    (:func:`d5rl.runner.results.seed_interval`) and the paper's (mean, ±) for the task's row, or None."""
    table = grid.table_cells(results, phase)
    order = grid.method_order({a for _, a in table})
    rows = []
    for task, algo in sorted(table, key=lambda k: (*grid.task_order(k[0]), order.index(k[1]))):
        cells = table[(task, algo)]
        scores = grid.score_table(cells, phase)[(task, algo)]
        lo, hi = grid.seed_interval(scores)
        paper = paper_result(task, algo, phase)
        rows.append(
            {
                "environment": grid.environment(task),
                "task": task,
                "algo": algo,
                "method": grid.method_name(algo),
                "n": int(scores.size),
                "mean": float(scores.mean()),
                "std": float(scores.std()),
                "text": render.mean_std(scores.mean(), scores.std()),
                "ci": [lo, hi],
                "ci_text": render.interval(lo, hi),
                "seeds": [c.seed for c in cells],
                "scores": json_floats(scores),
                "steps": render.steps_label(cells),
                "paper_task": paper_task(task),
                "paper": None if paper is None else list(paper),
                "paper_text": render.paper_entry(paper)
                + "".join(f" († also {repeat_text(w)})" for w in paper_repeats(task, algo, phase)),
            }
        )
    return rows


def run_summary(run_dir: Path) -> dict:
    """Cells, per-phase comparison tables, mean learning curves per (task, algorithm), what the agents did
    (the tasks' episode statistics) and videos of one run."""
    run_dir = Path(run_dir)
    results = grid.collect(run_dir)
    by_task: dict[str, list] = {}
    for r in results:
        if r.evals:
            by_task.setdefault(r.task, []).append(r)
    curves = []
    for task, cells in sorted(by_task.items()):
        for algo, (steps, mean, std) in grid.mean_curves(cells).items():
            curves.append(
                {
                    "task": task,
                    "algo": algo,
                    "method": grid.method_name(algo),
                    "steps": steps.tolist(),
                    "mean": json_floats(mean),
                    "std": json_floats(std),
                    "seeds": len({c.seed for c in cells if c.algo == algo}),
                }
            )
    tables = {}
    for phase in ("offline", "online"):
        rows = comparison_rows(results, phase)
        if rows:
            tables[phase] = rows
    cells = [
        {
            "task": r.task,
            "algo": r.algo,
            "method": grid.method_name(r.algo),
            "seed": r.seed,
            "done": r.done,
            "final": r.final,
            "evaluations": len(r.evals),
            "failures": r.failures,
            "videos": [os.path.relpath(v, run_dir) for v in r.videos[-grid.VIDEOS_PER_CELL :]],
        }
        for r in sorted(results, key=lambda r: (r.task, r.algo, r.seed))
    ]
    return {
        "name": run_dir.name,
        "path": str(run_dir),
        "cells": cells,
        "curves": curves,
        "tables": tables,
        "tasks": [
            {"task": t, "environment": grid.environment(t)}
            for t in sorted({r.task for r in results}, key=grid.task_order)
        ],
        "environments": [label for _, label in grid.ENVIRONMENTS],
        "methods": grid.method_order({r.algo for r in results}),
        "behaviour": grid.behaviour_table(results),
        "behaviour_note": render.BEHAVIOUR_NOTE,
    }
