"""Statistics for comparing learners over few seeds (the study of docs/results.md).

The choices follow Agarwal et al., "Deep RL at the edge of the statistical precipice"
(NeurIPS 2021), whose library is rliable: an interquartile mean (IQM) instead of a mean
or a median, 95 % bootstrap intervals instead of a "±", performance profiles instead of
one number. rliable itself pulls in arch and its own plotting; scipy's bootstrap does the
same resampling here. Differences between algorithms are paired by seed, because the
runner gives every algorithm of one seed the same network start, noise and start states.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 10_000
# scipy 1.15 on names bootstrap's generator `rng`; before, `random_state` (a ROS install's
# rosdep key python3-scipy is 1.11 on Ubuntu 24.04). The same Generator, the same resamples.
_GENERATOR_KEYWORD = 'rng' if 'rng' in inspect.signature(stats.bootstrap).parameters else 'random_state'


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
        **{_GENERATOR_KEYWORD: np.random.default_rng(seed)},
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


# ----------------------------------------------------------------- pre-stated paired tests


@dataclass(frozen=True)
class PairedTest:
    """Same-seed differences a[s] - b[s] judged as a study plan states in advance: the mean with
    its t interval, a two-sided sign-flip permutation p-value, and an equivalence test (TOST)
    against +-margin. ``holm`` is filled in over the family of primary comparisons."""

    n: int
    mean: float
    low: float  # 95 % t interval
    high: float
    p: float  # two-sided sign-flip permutation test of a zero mean difference
    tost_p: float  # the larger of the two one-sided t tests of |mean| >= margin
    margin: float
    holm: float = float('nan')

    def verdict(self, alpha: float = 0.05) -> str:
        p = self.holm if not np.isnan(self.holm) else self.p
        if p < alpha:
            return 'different'
        if self.tost_p < alpha:
            return f'equivalent within ±{self.margin:g}'
        return 'unresolved'


def t_interval(diffs, confidence: float = CONFIDENCE) -> tuple[float, float]:
    diffs = np.asarray(diffs, dtype=float)
    if len(diffs) < 2:
        return float('nan'), float('nan')
    half = stats.t.ppf(0.5 + confidence / 2, len(diffs) - 1) * diffs.std(ddof=1) / np.sqrt(len(diffs))
    return float(diffs.mean() - half), float(diffs.mean() + half)


def sign_flip_p(diffs, resamples: int = 200_000, seed: int = 0) -> float:
    """P(|mean of randomly sign-flipped differences| >= |observed mean|): exact over all 2^n
    flips for n <= 16, else estimated from ``resamples`` random flips (counting the observed one)."""
    diffs = np.asarray(diffs, dtype=float)
    n = len(diffs)
    if n == 0:
        return float('nan')
    observed = abs(diffs.mean())
    if n <= 16:
        signs = 1 - 2 * ((np.arange(2**n)[:, None] >> np.arange(n)) & 1)
        return float((np.abs(signs @ diffs / n) >= observed - 1e-12).mean())
    signs = np.random.default_rng(seed).choice((-1.0, 1.0), size=(resamples, n))
    extreme = int((np.abs(signs @ diffs / n) >= observed - 1e-12).sum())
    return (extreme + 1) / (resamples + 1)


def tost_p(diffs, margin: float) -> float:
    """Two one-sided t tests of H0: mean <= -margin and H0: mean >= +margin; the larger p.
    Below alpha: the mean difference lies within +-margin (the (1 - 2 alpha) t interval does)."""
    diffs = np.asarray(diffs, dtype=float)
    n = len(diffs)
    if n < 2:
        return float('nan')
    se = diffs.std(ddof=1) / np.sqrt(n)
    if se == 0:
        return 0.0 if abs(diffs.mean()) < margin else 1.0
    lower = stats.t.sf((diffs.mean() + margin) / se, n - 1)
    upper = stats.t.cdf((diffs.mean() - margin) / se, n - 1)
    return float(max(lower, upper))


def holm(pvalues) -> list:
    """Holm's step-down adjustment of a family of p-values (in their order)."""
    p = np.asarray(pvalues, dtype=float)
    order = np.argsort(p)
    adjusted, running = np.empty_like(p), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p) - rank) * p[i]))
        adjusted[i] = running
    return adjusted.tolist()


def paired_test(a: dict, b: dict, margin: float, seed: int = 0) -> PairedTest:
    common = sorted(set(a) & set(b))
    diffs = np.array([a[s] - b[s] for s in common], dtype=float)
    diffs = diffs[~np.isnan(diffs)]
    low, high = t_interval(diffs)
    mean = float(diffs.mean()) if len(diffs) else float('nan')
    return PairedTest(len(diffs), mean, low, high, sign_flip_p(diffs, seed=seed), tost_p(diffs, margin), margin)
