"""The finished runs' episodes.csv and eval.csv gathered into one table each, for the reports."""

from __future__ import annotations

import csv
from pathlib import Path

from .seed_runs import run_dir

COLUMNS = (
    'algorithm',
    'seed',
    'episode',
    'return',
    'length',
    'advice_asked',
    'advice_given',
    'success',
    'human_time_s',
    'takeover_steps',
    'takeover_s',
    'asked_steps',
)


EVAL_COLUMNS = ('algorithm', 'seed', 'episode', 'start', 'return', 'length', 'success')


def gather(output: Path, algorithms, seeds, label: str = 'algorithm') -> Path:
    """Write <output>/episodes.csv from every finished run (and <output>/eval.csv from their
    advice-free evaluations, where they have one). ``label``: the first column's name (a
    study's runs are arms, not algorithms)."""
    _gather_eval(output, algorithms, seeds, label)
    path = output / 'episodes.csv'
    with path.open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow((label, *COLUMNS[1:]))
        for algorithm in algorithms:
            for seed in seeds:
                directory = run_dir(output, algorithm, seed)
                if not (directory / 'DONE').exists():
                    continue
                with (directory / 'episodes.csv').open(newline='') as run_csv:
                    # A column a run's record lacks (written before the column existed) was 0 then.
                    for row in csv.DictReader(run_csv):
                        writer.writerow([algorithm, seed, *(row.get(c, '0') for c in COLUMNS[2:])])
    return path


def _gather_eval(output: Path, algorithms, seeds, label: str = 'algorithm') -> None:
    rows = []
    for algorithm in algorithms:
        for seed in seeds:
            directory = run_dir(output, algorithm, seed)
            if (directory / 'DONE').exists() and (directory / 'eval.csv').exists():
                with (directory / 'eval.csv').open(newline='') as run_csv:
                    rows += [[algorithm, seed, *(r[c] for c in EVAL_COLUMNS[2:])] for r in csv.DictReader(run_csv)]
    if rows:
        with (output / 'eval.csv').open('w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow((label, *EVAL_COLUMNS[1:]))
            writer.writerows(rows)
