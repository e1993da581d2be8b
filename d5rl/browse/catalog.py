"""Tasks, datasets, episodes and dataset overviews as JSON-ready dicts for the browse page.

Datasets are opened with :func:`d5rl.datasets.loading.load_dataset` (checked, never generated, every
array memory-mapped, no camera-frame cache built: camera tasks load states only), and with the
task's own rewards (tasks that relabel a shared dataset show their own returns).
"""

from __future__ import annotations

import threading
import warnings
from pathlib import Path

import numpy as np

from d5rl.browse import families
from d5rl.datasets.generation import dataset_root, full_size
from d5rl.datasets.loading import load_dataset
from d5rl.datasets.status import dataset_status, disk_bytes
from d5rl.errors import D5RLError
from d5rl.registry import get_spec, list_tasks

DOCS = Path(__file__).resolve().parents[2] / "docs" / "datacards"  # present in a source checkout
MAX_SIGNAL_COLUMNS = 16  # infos arrays wider than this are not plotted per episode
BINS = 30


def json_floats(x) -> list:
    """Floats for JSON, rounded to 5 significant digits (NaN/inf as None)."""
    a = np.asarray(x, np.float64)
    out = np.where(np.isfinite(a), a, np.nan)
    out = np.array([float(f"{v:.5g}") if np.isfinite(v) else None for v in out.ravel()], dtype=object)
    return out.reshape(a.shape).tolist()


def datacard(spec) -> str | None:
    """File name of the task's data card under docs/datacards (when the checkout has one)."""
    for name in (spec.benchmark_group, spec.family, {"wx": "widowx"}.get(spec.family)):
        if name and (DOCS / f"{name}.md").is_file():
            return f"{name}.md"
    return None


def task_summary(task_id: str, sizes: dict | None = None) -> dict:
    """One task: spec, dataset spec, what is on disk (status, episodes, bytes), score references."""
    spec = get_spec(task_id)
    status, manifest = dataset_status(spec)
    out = {
        "id": spec.id,
        "family": spec.family,
        "group": spec.benchmark_group,
        "observation": spec.observation,
        "description": spec.description,
        "horizon": spec.max_episode_steps,
        "status": status,
        "score": None
        if spec.score is None
        else {"random": spec.score.random, "expert": spec.score.expert, "source": spec.score.source},
        "score_definition": spec.score_definition,
        "datacard": datacard(spec),
        "dataset": None,
        "on_disk": None,
    }
    d = spec.dataset
    if d is None:
        return out
    out["dataset"] = {
        "name": d.name,
        "version": d.version,
        "episodes": full_size(d),
        "generator": d.producer,
        "description": d.description,
        "seed": d.default_seed,
    }
    if manifest is not None:
        root = dataset_root(d)
        key = str(root)
        if sizes is not None and key not in sizes:
            sizes[key] = disk_bytes(root)
        out["on_disk"] = {
            "episodes": manifest["num_episodes"],
            "transitions": manifest["num_transitions"],
            "bytes": sizes[key] if sizes is not None else disk_bytes(root),
        }
    return out


def all_tasks() -> list[dict]:
    sizes: dict = {}  # tasks sharing a dataset count its bytes once
    return [task_summary(t, sizes) for t in list_tasks() if not t.startswith("test-")]


class Datasets:
    """Open datasets, one per task, kept for the life of the server (memory-mapped: cheap)."""

    def __init__(self):
        self._open: dict[str, object] = {}
        self._lock = threading.Lock()

    def get(self, task_id: str):
        spec = get_spec(task_id)
        if spec.dataset is None:
            raise D5RLError(f"{spec.id} has no dataset")
        with self._lock:
            if spec.id not in self._open:
                kwargs = {"render": False} if spec.dataset.derived else {}  # states only: no cache is built
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # a partial dataset is shown as what it is
                    self._open[spec.id] = load_dataset(
                        spec, generate=False, progress=False, in_memory=False, obs_keys=[], workers=1, **kwargs
                    )
            return self._open[spec.id]


def _returns(ds) -> np.ndarray:
    return np.add.reduceat(np.asarray(ds.rewards, np.float64), ds.episode_starts)


def _histogram(values, title: str, xlabel: str, bins: int = BINS) -> dict:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    counts, edges = np.histogram(v, bins=bins if v.size and np.ptp(v) > 0 else 1)
    return {
        "title": title,
        "x": json_floats((edges[:-1] + edges[1:]) / 2),
        "y": counts.tolist(),
        "width": json_floats(np.diff(edges)),
        "xlabel": xlabel,
        "ylabel": "count",
    }


def episodes_table(task_id: str, ds) -> dict:
    """Every episode: index, length, return, normalized score (when the data defines one)."""
    spec = get_spec(task_id)
    returns = _returns(ds)
    scores = families.episode_scores(spec, ds.episode_meta, returns)
    return {
        "task": spec.id,
        "lengths": ds.episode_lengths.tolist(),
        "returns": json_floats(returns),
        "scores": None if scores is None else json_floats(scores),
    }


def overview(task_id: str, ds) -> dict:
    """Histograms of return, length, score; per-episode counts of boolean ``infos`` columns (kitchen:
    subtasks completed), histograms of speeds (A1); the family's success profiles (WidowX)."""
    spec = get_spec(task_id)
    returns = _returns(ds)
    plots = [_histogram(returns, "Episode return", "return"), _histogram(ds.episode_lengths, "Episode length", "steps")]
    scores = families.episode_scores(spec, ds.episode_meta, returns)
    if scores is not None:
        plots.append(_histogram(scores, "Normalized score of the dataset's episodes", "normalized score"))
    for key in sorted(k for k in ds.arrays if k.startswith("infos/")):
        arr = ds.arrays[key]
        name = key[len("infos/") :]
        if arr.dtype == bool and arr.ndim == 2 and ds.aligns[key] == "transition":
            done = np.logical_or.reduceat(np.asarray(arr), ds.episode_starts, axis=0)  # (E, k): ever true
            per_ep = done.sum(axis=1)
            plots.append(
                {
                    "title": f"{name}: columns true at some step, per episode",
                    "x": list(range(arr.shape[1] + 1)),
                    "y": np.bincount(per_ep, minlength=arr.shape[1] + 1).tolist(),
                    "xlabel": "count",
                    "ylabel": "episodes",
                }
            )
            labels = families.column_labels(spec, key, arr.shape[1]) or [str(j) for j in range(arr.shape[1])]
            plots.append(
                {
                    "title": f"{name}: share of episodes where each column is true at some step",
                    "x": labels,
                    "y": json_floats(done.mean(axis=0)),
                    "xlabel": "",
                    "ylabel": "share of episodes",
                }
            )
        elif arr.ndim == 1 and arr.dtype.kind == "f" and "speed" in name:
            plots.append(_histogram(np.asarray(arr), f"{name} (every step)", name))
    plots += families.overview_extras(spec, ds)
    return {"task": spec.id, "episodes": ds.num_episodes, "transitions": ds.num_transitions, "plots": plots}


def episode_series(task_id: str, ds, index: int) -> dict:
    """One episode for the viewer: reward and return, every small ``infos`` array, the actions, its meta.

    ``x`` of a transition-aligned series is the transition index ``t`` (from frame ``t`` to ``t + 1``);
    of a step-aligned one the frame index."""
    spec = get_spec(task_id)
    if not 0 <= index < ds.num_episodes:
        raise IndexError(f"episode {index} is not in {spec.id}'s dataset ({ds.num_episodes} episodes on disk)")
    ep = ds.episode(index)
    a = ep.arrays
    rewards = np.asarray(a["rewards"], np.float64)
    panels = [
        {
            "title": "reward and return",
            "kind": "lines",
            "align": "transition",
            "series": [
                {"name": "reward", "y": json_floats(rewards)},
                {"name": "return", "y": json_floats(np.cumsum(rewards)), "axis": "y2"},
            ],
        }
    ]
    for key in sorted(k for k in a if k.startswith("infos/")):
        arr = np.asarray(a[key])
        align = "step" if len(arr) == len(rewards) + 1 else "transition"
        if arr.ndim > 2 or (arr.ndim == 2 and arr.shape[1] > MAX_SIGNAL_COLUMNS) or arr.dtype.kind not in "biuf":
            continue
        cols = arr.reshape(len(arr), -1)
        labels = families.column_labels(spec, key, cols.shape[1]) or (
            [key[6:]] if cols.shape[1] == 1 else [f"{key[6:]}[{j}]" for j in range(cols.shape[1])]
        )
        panel = {
            "title": key[6:],
            "kind": "flags" if arr.dtype == bool else "lines",
            "align": align,
            "series": [{"name": n, "y": json_floats(cols[:, j].astype(np.float64))} for j, n in enumerate(labels)],
        }
        values = families.value_labels(spec, key)
        if values:
            panel["value_labels"] = values
        panels.append(panel)
    actions = np.asarray(a["actions"], np.float64).reshape(len(rewards), -1)
    panels.append(
        {
            "title": "actions",
            "kind": "lines",
            "align": "transition",
            "series": [{"name": f"a[{j}]", "y": json_floats(actions[:, j])} for j in range(actions.shape[1])],
        }
    )
    scores = families.episode_scores(spec, [ep.meta], np.array([rewards.sum()]))
    return {
        "task": spec.id,
        "index": index,
        "episodes": ds.num_episodes,
        "length": len(rewards),
        "return": float(rewards.sum()),
        "score": None if scores is None else float(scores[0]),
        "terminal": bool(np.asarray(a["terminals"]).any()),
        "meta": ep.meta,
        "panels": panels,
    }
