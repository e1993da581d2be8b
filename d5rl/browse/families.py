"""What the browse page knows about each family beyond the generic arrays: column names of ``infos/*``
arrays, per-episode scores that are not a function of the return, and extra overview plots built from
the families' own data-card statistics."""

from __future__ import annotations

import numpy as np

from d5rl.envs.kitchen.subtasks import SUBTASK_NAMES
from d5rl.production.widowx.datacard_stats import stats
from d5rl.production.widowx.scripted import STAGES
from d5rl.registry import normalize_score


def column_labels(spec, key: str, ncols: int) -> list[str] | None:
    """Names of the columns of ``infos/<key>`` (kitchen: the subtasks of ``infos/completed``)."""
    if spec.family == "kitchen" and key == "infos/completed":
        return list(SUBTASK_NAMES) if len(SUBTASK_NAMES) == ncols else None
    return None


def value_labels(spec, key: str) -> list[str] | None:
    """Names of the integer values of a 1-D ``infos/<key>`` (WidowX: the scripted policy's stages)."""
    if spec.family == "wx" and key == "infos/stage":
        return list(STAGES)
    return None


def episode_scores(spec, metas: list[dict], returns: np.ndarray) -> np.ndarray | None:
    """Normalized score of dataset episodes (their metas and returns), or None where the data does not
    define one."""
    if spec.score_from == "return" and spec.score is not None:
        return np.asarray(normalize_score(spec, returns), np.float64)
    if spec.family == "wx" and all("num_sorted" in m for m in metas):
        return np.array([m["num_sorted"] / 2 for m in metas], np.float64)  # info["score"] at the end
    return None


def overview_extras(spec, ds) -> list[dict]:
    """Family plots for the dataset overview (bar charts: ``{title, x, y, xlabel, ylabel}``)."""
    if spec.family != "wx" or not ds.episode_meta or "placed_as_intended" not in ds.episode_meta[0]:
        return []

    s = stats(list(ds.episode_meta))
    stages = [k for k in s if k.startswith("stage")]
    out = []
    for measure in ("grasped (lifted off the table)", "placed in the intended bin", "ended in its correct bin"):
        out.append(
            {
                "title": f"Success profile: {measure}",
                "x": stages,
                "y": [s[k][measure] for k in stages],
                "xlabel": "stage of the script",
                "ylabel": "share of episodes",
            }
        )
    final = s["final objects sorted"]
    out.append(
        {
            "title": "Objects in their correct bin at the end",
            "x": [str(k) for k in final],
            "y": [final[k] for k in final],
            "xlabel": "objects sorted",
            "ylabel": "share of episodes",
        }
    )
    return out
