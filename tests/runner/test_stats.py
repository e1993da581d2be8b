"""IQM and the stratified bootstrap against brute-force computations."""

import itertools

import numpy as np
import pytest

from d5rl.runner.stats import bootstrap_replicates, iqm, stratified_bootstrap_ci


def brute_iqm(values):
    """Interquartile mean by the definition: drop the lowest and highest floor(n/4) values."""
    v = sorted(float(x) for x in values)
    k = len(v) // 4
    middle = v[k : len(v) - k]
    return sum(middle) / len(middle)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 12, 13])
def test_iqm_matches_definition(n):
    x = np.random.default_rng(n).normal(size=n)
    assert iqm(x) == pytest.approx(brute_iqm(x), abs=1e-12)


def test_iqm_matches_scipy_trim_mean():
    scipy_stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(0)
    for n in (4, 9, 10, 31):
        x = rng.exponential(size=n)
        assert iqm(x) == pytest.approx(scipy_stats.trim_mean(x, 0.25), abs=1e-12)


def test_iqm_ignores_outliers():
    assert iqm([0.0, 1.0, 1.0, 100.0]) == 1.0


def _all_resamples(strata):
    """Every stratified resample: per task, every n_t-tuple of run indices (with replacement)."""
    per_task = [list(itertools.product(range(len(s)), repeat=len(s))) for s in strata]
    return [[np.array(i) for i in combo] for combo in itertools.product(*per_task)]


def test_exhaustive_bootstrap_equals_brute_force():
    strata = [np.array([0.1, 0.5, 0.9]), np.array([0.2, 0.3, 1.4])]
    resamples = _all_resamples(strata)
    assert len(resamples) == 27 * 27
    brute = np.array([brute_iqm([strata[t][i] for t in range(2) for i in idx[t]]) for idx in resamples])
    got = bootstrap_replicates(strata, indices=resamples)
    np.testing.assert_allclose(got, brute, atol=1e-12)
    point, lo, hi = stratified_bootstrap_ci(strata, indices=resamples)
    assert point == pytest.approx(brute_iqm(np.concatenate(strata)))
    assert lo == pytest.approx(np.percentile(brute, 2.5))
    assert hi == pytest.approx(np.percentile(brute, 97.5))


def test_random_bootstrap_converges_to_exact_distribution():
    strata = [np.array([0.0, 0.4, 1.0]), np.array([0.3, 0.35, 2.0]), np.array([0.5, 0.9])]
    exact = bootstrap_replicates(strata, indices=_all_resamples(strata))  # 27·27·4 equally likely resamples
    draws = bootstrap_replicates(strata, reps=40_000, rng=np.random.default_rng(1))
    assert draws.mean() == pytest.approx(exact.mean(), abs=0.005)
    assert draws.std() == pytest.approx(exact.std(), abs=0.005)
    for q in (10, 50, 90):  # CDFs agree (quantiles of a discrete law can jump, so compare probabilities)
        t = np.percentile(exact, q)
        assert np.mean(draws <= t) == pytest.approx(np.mean(exact <= t), abs=0.01)


def test_resampling_is_stratified():
    # one task all zeros, one all ones, same size: a stratified resample always pools half/half
    strata = [np.zeros(4), np.ones(4)]
    draws = bootstrap_replicates(strata, statistic=lambda x: float(np.mean(x)), reps=500, rng=np.random.default_rng(0))
    assert np.all(draws == 0.5)
    # the vectorised IQM path too
    point, lo, hi = stratified_bootstrap_ci(strata, reps=500, rng=np.random.default_rng(0))
    assert point == lo == hi == 0.5


def test_vectorised_path_matches_loop():
    strata = [np.random.default_rng(i).normal(size=n) for i, n in enumerate((3, 5, 4))]
    fast = bootstrap_replicates(strata, reps=300, rng=np.random.default_rng(7))
    slow = bootstrap_replicates(strata, statistic=lambda x: iqm(x), reps=300, rng=np.random.default_rng(7))
    np.testing.assert_allclose(fast, slow, atol=1e-12)


def test_rliable_agrees_if_installed():
    rly = pytest.importorskip("rliable.metrics")
    x = np.random.default_rng(3).normal(size=(5, 4))
    assert iqm(x) == pytest.approx(rly.aggregate_iqm(x))


def test_vectorised_mean_equals_the_statistic_applied_to_each_resample():
    strata = [np.array([0.0, 0.4, 1.0]), np.array([0.3, 2.0])]
    fast = bootstrap_replicates(strata, np.mean, reps=500, rng=np.random.default_rng(3))
    slow = bootstrap_replicates(strata, lambda x: float(np.mean(x)), reps=500, rng=np.random.default_rng(3))
    np.testing.assert_allclose(fast, slow, atol=1e-12)
