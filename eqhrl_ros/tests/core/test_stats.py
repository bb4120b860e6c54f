"""The study's statistics: IQM, bootstrap intervals, same-seed differences, profiles."""

import math

import numpy as np

from eqhrl_ros.stats import bootstrap, iqm, iqm_estimate, paired_difference, performance_profile


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
