"""Statistics for comparing learners over few seeds (the study of docs/results.md).

The choices follow Agarwal et al., "Deep RL at the edge of the statistical precipice"
(NeurIPS 2021), whose library is rliable: an interquartile mean (IQM) instead of a mean
or a median, 95 % bootstrap intervals instead of a "±", performance profiles instead of
one number. rliable itself pulls in arch and its own plotting; scipy's bootstrap does the
same resampling here. Differences between algorithms are paired by seed, because the
runner gives every algorithm of one seed the same network start, noise and start states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 10_000


def iqm(values, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50 % (scipy's trim_mean, 25 % cut each side)."""
    return stats.trim_mean(np.asarray(values, dtype=float), 0.25, axis=axis)


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its 95 % bootstrap interval over ``n`` values."""

    value: float
    low: float
    high: float
    n: int

    def text(self, digits: int = 1) -> str:
        if np.isnan(self.value):
            return '—'
        if np.isnan(self.low):
            return f'{self.value:.{digits}f} (n={self.n})'
        return f'{self.value:.{digits}f} [{self.low:.{digits}f}, {self.high:.{digits}f}]'


def bootstrap(values, statistic=np.mean, seed: int = 0) -> Estimate:
    """``statistic`` of ``values`` (NaN dropped) with a 95 % percentile bootstrap interval.
    Fewer than 3 values, or values all equal: no interval (NaN bounds)."""
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if len(values) == 0:
        return Estimate(float('nan'), float('nan'), float('nan'), 0)
    value = float(statistic(values))
    if len(values) < 3 or np.all(values == values[0]):
        return Estimate(value, float('nan'), float('nan'), len(values))
    result = stats.bootstrap(
        (values,),
        statistic,
        confidence_level=CONFIDENCE,
        n_resamples=RESAMPLES,
        method='percentile',
        rng=np.random.default_rng(seed),
        vectorized=True,
        axis=-1,
    )
    interval = result.confidence_interval
    return Estimate(value, float(interval.low), float(interval.high), len(values))


def iqm_estimate(values, seed: int = 0) -> Estimate:
    return bootstrap(values, lambda x, axis=-1: iqm(x, axis=axis), seed)


def paired_difference(a: dict, b: dict, seed: int = 0) -> tuple[Estimate, int, int]:
    """Mean of a[s] - b[s] over the seeds both have (a value per seed in each dict), its 95 %
    bootstrap interval, and (seeds where a > b, seeds compared)."""
    common = sorted(set(a) & set(b))
    diffs = np.array([a[s] - b[s] for s in common], dtype=float)
    diffs = diffs[~np.isnan(diffs)]
    return bootstrap(diffs, seed=seed), int((diffs > 0).sum()), len(diffs)


def performance_profile(values, taus) -> np.ndarray:
    """The fraction of runs whose score exceeds each tau (a performance profile's curve)."""
    values = np.asarray(values, dtype=float)
    return np.array([(values > tau).mean() for tau in taus])
