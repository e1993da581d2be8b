"""Reading a cell's evaluation log: the contract between trainers and the report.

A trainer writes its evaluations to ``eval.csv`` / ``eval.jsonl`` (or, as
:mod:`d5rl.training.loop` does, to ``metrics.jsonl`` among its other metric rows)
in the cell directory, one row per evaluation, with at least

* ``step``  — gradient steps done so far (offline steps count first, online after),
* ``score`` — the mean *normalized* score of the evaluation episodes
  (or ``eval/<task>/score``, the documented metric name; rows without a score
  are training metrics and are ignored),

and optionally ``phase`` (``offline`` / ``online``), ``return`` (raw mean
return), ``episodes``.  Without ``phase``, rows with ``step <= offline_steps``
are offline.  The final score of a phase is its *last* evaluation.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from d5rl.training.logger import read_rows
from d5rl.training.rundir import RunDir


def _score_key(row: dict, task: str | None) -> str | None:
    for key in ("score", "normalized_score", f"eval/{task}/score" if task else None):
        if key and key in row:
            return key
    cands = [k for k in row if k.startswith("eval/") and k.endswith("/score")]
    return cands[0] if len(cands) == 1 else None


def _num(v):
    if v is None or v == "":
        return None
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def read_evals(cell_dir: Path, task: str | None = None, offline_steps: int | None = None) -> list[dict]:
    """Rows ``{"step": int, "phase": str, "score": float, "return": float|None}`` sorted by step."""
    path = RunDir(cell_dir).eval_file()
    if path is None:
        return []
    if path.suffix == ".jsonl":
        raw = read_rows(path)  # bounded, and a damaged line is one error naming it
    else:
        with open(path, newline="") as f:
            raw = list(csv.DictReader(f))
    rows = []
    for r in raw:
        key = _score_key(r, task)
        score = _num(r.get(key)) if key else None
        step = _num(r.get("step"))
        if score is None or step is None or not math.isfinite(score):
            continue
        phase = r.get("phase") or None
        if phase is None:
            phase = "offline" if offline_steps is None or step <= offline_steps else "online"
        rows.append(
            {
                "step": int(step),
                "phase": str(phase),
                "score": score,
                "return": _num(r.get("return", r.get("eval/return"))),
            }
        )
    rows.sort(key=lambda r: (r["step"], r["phase"] != "offline"))
    return rows


def final_scores(rows: list[dict]) -> dict[str, float]:
    """``{"offline": last offline score, "online": last online score}`` (keys only if present)."""
    out = {}
    for r in rows:  # sorted by step: the last row of a phase wins
        out[r["phase"]] = r["score"]
    return out
