"""The figures docs/results.md quotes beyond eqhrl-report's tables, from the raw CSVs.

    .venv/bin/python tools/results_checks.py

Prints, for Pendulum: same-seed differences from SAC over episodes 100-199 (mean over the
seeds with a 95 % percentile-bootstrap interval over seeds: eqhrl_ros.reports.stats.bootstrap,
10,000 resamples, seeded 0), advice given per seed, and whether episodes 30-49 are
identical across algorithms; for LunarLander: QASAC minus SAC over episodes 50-69 per seed,
and successful episodes per run (all, and in the last 10). For the decisive study
(docs/results/study_pendulum_decisive): whether the exact E(s) changes the answer, on the
seeds both estimators ran (EQSAC minus its timing-matched random arm, for each estimator, and
the difference between the two, same seeds, 95 % t intervals: eqhrl_ros.reports.stats.t_interval).
"""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

from eqhrl_ros.reports.stats import bootstrap, t_interval

RESULTS = Path(__file__).resolve().parents[1] / 'docs' / 'results'


def load(env: str) -> dict:
    runs = defaultdict(dict)
    with (RESULTS / env / 'episodes.csv').open(newline='') as f:
        for row in csv.DictReader(f):
            runs[(row['algorithm'], int(row['seed']))][int(row['episode'])] = row
    return runs


def mean_return(run: dict, episodes: range) -> float:
    return float(np.mean([float(run[e]['return']) for e in episodes]))


def main() -> None:
    pendulum = load('pendulum')
    seeds = sorted({seed for _, seed in pendulum})
    for algorithm in ('qasac', 'eqsac'):
        diffs = [
            mean_return(pendulum[(algorithm, s)], range(100, 200)) - mean_return(pendulum[('sac', s)], range(100, 200))
            for s in seeds
        ]
        interval = bootstrap(diffs)
        low, high = interval.low, interval.high
        print(
            f'Pendulum {algorithm} - sac, episodes 100-199: {np.mean(diffs):+.1f} [{low:+.1f}, {high:+.1f}] '
            f'(per seed {", ".join(f"{d:+.1f}" for d in diffs)})'
        )
        given = [sum(int(r['advice_given']) for r in pendulum[(algorithm, s)].values()) for s in seeds]
        print(f'Pendulum {algorithm} advice given per seed: {given}')
    identical = all(
        len({pendulum[(a, s)][e]['return'] for a in ('sac', 'qasac', 'eqsac')}) == 1
        for s in seeds
        for e in range(30, 50)
    )
    print(f'Pendulum episodes 30-49 identical across algorithms for every seed: {identical}')

    lunar = load('lunar_lander')
    for s in sorted({seed for _, seed in lunar}):
        lead = mean_return(lunar[('qasac', s)], range(50, 70)) - mean_return(lunar[('sac', s)], range(50, 70))
        print(f'LunarLander seed {s}: qasac - sac, episodes 50-69: {lead:+.0f}')
        for algorithm in ('sac', 'qasac', 'eqsac'):
            run = lunar[(algorithm, s)]
            wins = [e for e, r in run.items() if r['success'] == '1']
            last = max(run) - 9
            print(f'  {algorithm}: {len(wins)} successful episodes, {sum(e >= last for e in wins)} in the last 10')


def decisive() -> None:
    """AUC per (arm, seed) of the decisive study's advice-free evaluations, and the estimator check."""
    path = RESULTS / 'study_pendulum_decisive' / 'eval.csv'
    if not path.exists():
        return
    curves = defaultdict(lambda: defaultdict(list))
    with path.open(newline='') as f:
        for row in csv.DictReader(f):
            curves[(row['arm'], int(row['seed']))][int(row['episode'])].append(float(row['return']))
    auc = {key: float(np.mean([np.mean(v) for v in by_episode.values()])) for key, by_episode in curves.items()}
    seeds = sorted(s for a, s in auc if a == 'eqsac_mc32' and ('random_eqsac_mc32', s) in auc)
    if len(seeds) < 2:
        return
    gaps = {}
    for arm, matched in (('eqsac', 'random_eqsac'), ('eqsac_mc32', 'random_eqsac_mc32')):
        gaps[arm] = np.array([auc[(arm, s)] - auc[(matched, s)] for s in seeds])
        low, high = t_interval(gaps[arm])
        span = f'{seeds[0]}-{seeds[-1]}'
        print(f'decisive, seeds {span}: {arm} - {matched}: {gaps[arm].mean():+.1f} [{low:+.1f}, {high:+.1f}]')
    change = gaps['eqsac'] - gaps['eqsac_mc32']
    low, high = t_interval(change)
    print(
        f'decisive: (exact - its random) - (K = 32 - its random), same seeds: {change.mean():+.1f} '
        f'[{low:+.1f}, {high:+.1f}]'
    )


if __name__ == '__main__':
    main()
    decisive()
