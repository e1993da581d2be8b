"""Aggregate statistics over runs: IQM and stratified-bootstrap confidence intervals.

This is the method of Agarwal et al., "Deep RL at the Edge of the Statistical
Precipice" (NeurIPS 2021; the ``rliable`` package), in plain numpy:

* **IQM** (interquartile mean): the mean of the middle 50 % of all normalized
  scores of an algorithm, pooled over tasks and seeds.  As in ``rliable`` (which
  calls ``scipy.stats.trim_mean(x, 0.25)``), ``floor(0.25·n)`` scores are cut
  from each end of the sorted list.
* **Stratified bootstrap**: each replicate resamples, *within every task
  separately*, that task's runs with replacement (so every task keeps its number
  of runs), and recomputes the statistic on the pooled resample.  The interval
  is the percentile interval of the replicates (``rliable``'s default method).

Scores are given per task as a list of 1-D arrays (ragged: a task may have fewer
seeds if a run failed).

Why not ``rliable`` itself: rliable 1.2.0 installs under requirements/lock.txt but fails to import
(``deprecate_kwarg() missing 1 required positional argument`` from its arch/statsmodels stack with
pandas 3), and would add arch, pandas, seaborn and statsmodels to the install.  These ~100 lines are
tested against ``scipy.stats.trim_mean`` and against exhaustive enumeration of every resample
(tests/runner/test_stats.py).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from d5rl.errors import D5RLError


def iqm(scores) -> float:
    """Interquartile mean of all values (any shape, NaNs not allowed)."""
    x = np.sort(np.asarray(scores, np.float64).ravel())
    n = x.size
    if n == 0:
        raise D5RLError("IQM of no scores", "check that the runs produced evaluation logs")
    k = int(0.25 * n)
    return float(x[k : n - k].mean())


def _as_strata(scores_per_task) -> list[np.ndarray]:
    if isinstance(scores_per_task, np.ndarray) and scores_per_task.ndim == 2:
        # rliable layout: (num_runs, num_tasks)
        strata = [scores_per_task[:, j] for j in range(scores_per_task.shape[1])]
    else:
        strata = [np.asarray(s, np.float64).ravel() for s in scores_per_task]
    strata = [s for s in strata if s.size]
    if not strata:
        raise D5RLError("no scores to aggregate", "check that the runs produced evaluation logs")
    return strata


def bootstrap_replicates(
    scores_per_task,
    statistic: Callable = iqm,
    reps: int = 2000,
    rng: np.random.Generator | None = None,
    indices: Sequence[Sequence[np.ndarray]] | None = None,
) -> np.ndarray:
    """The statistic on ``reps`` stratified resamples.

    ``indices`` (optional, for exhaustive checks) gives the resamples explicitly:
    ``indices[r][t]`` are the run indices drawn for task ``t`` in replicate ``r``.
    """
    strata = _as_strata(scores_per_task)
    if indices is None:
        if rng is None:
            rng = np.random.default_rng(0)
        # one (reps, n_t) index matrix per task; draws are independent across tasks
        draws = [rng.integers(0, s.size, size=(reps, s.size)) for s in strata]
        if statistic is iqm or statistic is np.mean:  # vectorised over one (reps, N) matrix
            pooled = np.concatenate([s[d] for s, d in zip(strata, draws)], axis=1)
            if statistic is np.mean:
                return pooled.mean(axis=1)
            pooled.sort(axis=1)
            n = pooled.shape[1]
            k = int(0.25 * n)
            return pooled[:, k : n - k].mean(axis=1)
        indices = [[d[r] for d in draws] for r in range(reps)]
    out = np.empty(len(indices), np.float64)
    for r, idx in enumerate(indices):
        out[r] = statistic(np.concatenate([s[i] for s, i in zip(strata, idx)]))
    return out


def stratified_bootstrap_ci(
    scores_per_task,
    statistic: Callable = iqm,
    reps: int = 2000,
    confidence: float = 0.95,
    rng: np.random.Generator | None = None,
    indices=None,
) -> tuple[float, float, float]:
    """``(point estimate, lower, upper)`` of ``statistic`` with a percentile bootstrap interval."""
    strata = _as_strata(scores_per_task)
    point = statistic(np.concatenate(strata))
    reps_values = bootstrap_replicates(strata, statistic, reps, rng, indices)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.percentile(reps_values, [100 * alpha, 100 * (1 - alpha)])
    return float(point), float(lo), float(hi)
