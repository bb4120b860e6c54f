"""The study's statistics: IQM, bootstrap intervals, same-seed differences, profiles."""

import math

import numpy as np
import pytest
from scipy import stats

from eqhrl_ros.reports.stats import bootstrap, iqm, iqm_estimate, paired_difference, performance_profile


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm([1, 2, 3, 4, 5, 6, 7, 100]) == np.mean([3, 4, 5, 6])
    assert iqm([[1, 2, 3, 4], [0, 0, 8, 8]], axis=1).tolist() == [2.5, 4.0]


def test_bootstrap_interval_holds_the_estimate_and_narrows_with_more_seeds():
    rng = np.random.default_rng(0)
    few, many = bootstrap(rng.normal(10, 2, 5)), bootstrap(rng.normal(10, 2, 200))
    assert few.low < few.value < few.high and many.low < many.value < many.high
    assert many.high - many.low < few.high - few.low
    assert 9.0 < many.low and many.high < 11.0
    assert bootstrap([1.0, 2.0, 3.0]).text() == f'2.0 [{bootstrap([1.0, 2.0, 3.0]).low:.1f}, 3.0]'


def test_bootstrap_without_an_interval_says_so():
    assert math.isnan(bootstrap([4.0, 4.0, 4.0]).low)
    assert bootstrap([1.0, 2.0]).text() == '1.5 (n=2)'
    assert bootstrap([]).text() == '—'
    assert bootstrap([1.0, float('nan'), 3.0, 5.0]).n == 3


def test_iqm_estimate_resists_an_outlier_seed():
    estimate = iqm_estimate([1, 2, 3, 4, 1000])
    assert estimate.value == 3.0 and estimate.high < 1000


def test_paired_difference_uses_only_shared_seeds_and_counts_wins():
    a = {0: 5.0, 1: 6.0, 2: 7.0, 3: 1.0}
    b = {0: 4.0, 1: 4.0, 2: 8.0, 9: 0.0}
    estimate, wins, n = paired_difference(a, b)
    assert (wins, n) == (2, 3) and estimate.value == np.mean([1.0, 2.0, -1.0])


def test_performance_profile_is_the_fraction_above_each_score():
    assert performance_profile([1, 2, 3, 4], [0, 2, 4]).tolist() == [1.0, 0.5, 0.0]


def test_sign_flip_p_is_exact_for_few_seeds_and_matches_the_t_test_for_many():
    from eqhrl_ros.reports.stats import sign_flip_p

    # Three differences of one sign: of 8 sign patterns, 2 are as extreme (all + and all -).
    assert sign_flip_p([1.0, 2.0, 3.0]) == pytest.approx(0.25)
    rng = np.random.default_rng(0)
    diffs = rng.normal(0.5, 1.0, 30)
    t_p = stats.ttest_1samp(diffs, 0.0).pvalue
    assert sign_flip_p(diffs) == pytest.approx(t_p, abs=0.02)


def test_tost_says_equivalent_only_when_the_90_percent_interval_is_inside_the_margin():
    from eqhrl_ros.reports.stats import t_interval, tost_p

    rng = np.random.default_rng(1)
    tight = rng.normal(0.3, 2.0, 40)
    low, high = t_interval(tight, confidence=0.90)
    assert (tost_p(tight, 5.0) < 0.05) == (-5.0 < low and high < 5.0) and tost_p(tight, 5.0) < 0.05
    assert tost_p(tight, 0.1) > 0.05
    assert tost_p(rng.normal(8.0, 2.0, 40), 5.0) > 0.5


def test_holm_adjusts_in_step_down_order():
    from eqhrl_ros.reports.stats import holm

    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5]) == [0.5]


def test_a_paired_test_gives_a_verdict():
    from eqhrl_ros.reports.stats import paired_test

    a = {s: 10.0 + s % 3 for s in range(30)}
    same = paired_test(a, {s: v + 0.1 * (-1) ** s for s, v in a.items()}, margin=5.0)
    assert same.n == 30 and same.verdict() == 'equivalent within ±5'
    apart = paired_test({s: v + 9 + (s % 2) for s, v in a.items()}, a, margin=5.0)
    assert apart.verdict() == 'different' and apart.low > 5


def test_a_scipy_whose_bootstrap_takes_random_state_gives_the_same_intervals(monkeypatch):
    """scipy before 1.15 (1.11 is Ubuntu 24.04's python3-scipy, what rosdep installs on a ROS
    install) names bootstrap's generator `random_state`: `rng=` there was a TypeError."""
    import importlib
    from dataclasses import astuple

    import eqhrl_ros.reports.stats as study_stats

    values = np.random.default_rng(3).normal(10, 2, 12)
    expected = (astuple(study_stats.bootstrap(values)), astuple(study_stats.iqm_estimate(values)))
    scipy_bootstrap, keyword = stats.bootstrap, study_stats._GENERATOR_KEYWORD  # this scipy's own

    def bootstrap_of_scipy_1_11(data, statistic, *, vectorized=None, axis=0, confidence_level=0.95,
                                n_resamples=9999, method='BCa', random_state=None):  # fmt: skip
        return scipy_bootstrap(data, statistic, vectorized=vectorized, axis=axis, confidence_level=confidence_level,
                               n_resamples=n_resamples, method=method, **{keyword: random_state})  # fmt: skip

    monkeypatch.setattr(stats, 'bootstrap', bootstrap_of_scipy_1_11)
    try:
        older = importlib.reload(study_stats)
        assert (astuple(older.bootstrap(values)), astuple(older.iqm_estimate(values))) == expected
    finally:
        monkeypatch.undo()
        importlib.reload(study_stats)
