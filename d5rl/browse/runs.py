"""``d5rl bench`` run directories for the browse page: read with :func:`d5rl.runner.report.collect` (the
report's own reader), summarized as learning curves, score tables and rollout videos."""

from __future__ import annotations

import os
from pathlib import Path

from d5rl.browse.catalog import json_floats
from d5rl.runner import report


def run_summary(run_dir: Path) -> dict:
    """Cells, mean learning curves per (task, algorithm), final-score tables, what the agents did (the tasks'
    episode statistics) and videos of one run."""
    run_dir = Path(run_dir)
    results = report.collect(run_dir)
    by_task: dict[str, list] = {}
    for r in results:
        if r.evals:
            by_task.setdefault(r.task, []).append(r)
    curves = []
    for task, cells in sorted(by_task.items()):
        for algo, (steps, mean, std) in report.mean_curves(cells).items():
            curves.append({"task": task, "algo": algo, "method": report.method_name(algo),
                           "steps": steps.tolist(), "mean": json_floats(mean), "std": json_floats(std),
                           "seeds": len({c.seed for c in cells if c.algo == algo})})
    tables = {}
    for phase in ("offline", "online"):
        table = report.score_table(results, phase)
        if table:
            tables[phase] = [{"environment": report.environment(t), "task": t, "algo": a,
                              "method": report.method_name(a), "mean": float(v.mean()), "std": float(v.std()),
                              "n": int(v.size)} for (t, a), v in sorted(table.items())]
    cells = [{"task": r.task, "algo": r.algo, "method": report.method_name(r.algo), "seed": r.seed, "done": r.done,
              "final": r.final, "evaluations": len(r.evals), "failures": r.failures,
              "videos": [os.path.relpath(v, run_dir) for v in r.videos[-report.VIDEOS_PER_CELL:]]}
             for r in sorted(results, key=lambda r: (r.task, r.algo, r.seed))]
    return {"name": run_dir.name, "path": str(run_dir), "cells": cells, "curves": curves, "tables": tables,
            "behaviour": report.behaviour_table(results), "behaviour_note": report.BEHAVIOUR_NOTE}
