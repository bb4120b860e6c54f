"""What eqhrl-report reads and makes: the runs' episodes.csv and eval.csv per algorithm, the
summary table and the figures (eqhrl-report's docstring says what each holds)."""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..core.algorithm.config import MODE_COLORS, MODE_LABELS, MODES
from ..core.runs.provenance import PROVENANCE_FILE
from ..files.yaml_files import load_mapping
from .plots import smooth

ORDER = MODES  # the algorithms in the order tables and figures show them
LABELS, COLORS = MODE_LABELS, MODE_COLORS
# Return thresholds for "episodes to reach": LunarLander's solved line; for Pendulum
# (100-step episodes) a return at which the pendulum is swung up and held.
THRESHOLDS = {'LunarLanderContinuous-v3': 200.0, 'Pendulum-v1': -200.0}


def return_threshold(env_id: str, given=None, say=None) -> float:
    """The return "episodes to reach" counts to: ``given`` (--threshold), else THRESHOLDS, else the
    env's gymnasium ``reward_threshold``, else 0, and then ``say`` (print) is told that 0 is no
    threshold of the env's (before, 2026-12-05, the double integrator's report used 0 unsaid)."""
    if given is not None:
        return float(given)
    if env_id in THRESHOLDS:
        return THRESHOLDS[env_id]
    import gymnasium

    spec = gymnasium.envs.registry.get(env_id)
    if spec is not None and spec.reward_threshold is not None:
        return float(spec.reward_threshold)
    if say is not None:
        say(
            f'{env_id or "this env"} has no return threshold of its own: '
            "'episodes to return ≥ 0' counts to 0 (give --threshold)"
        )
    return 0.0


def last_start(folder) -> dict:
    """The latest entry of a run folder's provenance.yaml (the learner notes its env, mode and seed
    there); {} where there is none or it cannot be read."""
    path = Path(folder) / PROVENANCE_FILE
    try:
        starts = load_mapping(path, 'provenance file').get('starts') if path.exists() else None
    except ValueError:
        return {}
    return starts[-1] if isinstance(starts, list) and starts and isinstance(starts[-1], dict) else {}


def read_runs(folders) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    """{(algorithm, seed): {column: values sorted by episode}} from every folder: an eqhrl-experiment
    output (its episodes.csv names each row's algorithm and seed), or a single run's folder
    (eqhrl-train, ros2 launch: its mode and seed from provenance.yaml; a run from before they were
    noted there is named by its folder, seed 0). Before, a single run's folder raised KeyError.
    One algorithm and seed in two folders is refused (its rows would mix into one run)."""
    rows, where = defaultdict(list), {}
    resolved = [Path(folder).resolve() for folder in folders]
    for folder, place in zip(folders, resolved):
        if resolved.count(place) > 1:  # its rows would be read twice
            raise ValueError(f'{folder} is given more than once')
    for folder in folders:
        path = Path(folder) / 'episodes.csv'
        if not path.exists():
            raise FileNotFoundError(f'{path}: no episodes.csv (an eqhrl-experiment output or a run folder)')
        with path.open(newline='') as f:
            reader = csv.DictReader(f)
            single = not {'algorithm', 'seed'} <= set(reader.fieldnames or ())
            if single:
                start = last_start(folder)
                run = (str(start.get('mode') or Path(folder).resolve().name), int(start.get('seed', 0)))
            for row in reader:
                _check_numbers(row, path, reader.line_num, RUN_COLUMNS)
                key = run if single else (row['algorithm'], int(row['seed']))
                if where.setdefault(key, folder) != folder:
                    raise ValueError(
                        f'{where[key]} and {folder} both hold {key[0]} seed {key[1]}: give one of them, or '
                        'an eqhrl-experiment output that holds both'
                    )
                rows[key].append(row)
    runs = {}
    for key, items in rows.items():
        items.sort(key=lambda r: int(r['episode']))
        runs[key] = {column: np.array([float(r[column]) for r in items]) for column in RUN_COLUMNS}
    return runs


RUN_COLUMNS = ('episode', 'return', 'length', 'advice_asked', 'advice_given', 'success')  # what the report reads


def _check_numbers(row: dict, path: Path, line: int, columns) -> None:
    """ValueError naming the file, the line and the column of a value the report cannot read (a row
    torn by a kill, a hand edit): before, a traceback (a torn row) or a line that named the value only."""
    for column in (*columns, *(('seed',) if 'seed' in row else ())):
        value = row.get(column)
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number) or (column in ('episode', 'seed') and not number.is_integer()):
            raise ValueError(f'{path}, line {line}: {column} is {value!r}, not a number this report can read')


def env_of(folders) -> str:
    """The env of the runs: an eqhrl-experiment output's settings.yaml, else a run's provenance."""
    for folder in folders:
        settings = Path(folder) / 'settings.yaml'
        if settings.exists():
            return load_mapping(settings, 'settings file').get('env_id', '')
        if last_start(folder).get('env'):
            return str(last_start(folder)['env'])
    return ''


def episodes_to_reach(returns: np.ndarray, threshold: float) -> float:
    reached = np.nonzero(smooth(returns) >= threshold)[0]
    return float(reached[0]) if len(reached) else math.nan


def summarize(runs, threshold: float) -> list[dict]:
    """One dict per algorithm; each statistic as (mean, std) over seeds."""
    table = []
    algorithms = sorted({a for a, _ in runs}, key=lambda a: (ORDER.index(a) if a in ORDER else 99, a))
    for algorithm in algorithms:
        per_run = [runs[key] for key in sorted(runs) if key[0] == algorithm]

        def stat(values):  # mean and spread over runs; one run has no spread (not '± 0')
            values = np.asarray(values, dtype=float)
            return float(values.mean()), float(values.std()) if len(values) > 1 else math.nan

        tail = [max(1, len(r['return']) // 10) for r in per_run]
        reach = [episodes_to_reach(r['return'], threshold) for r in per_run]
        reached = [x for x in reach if not math.isnan(x)]
        table.append(
            {
                'algorithm': algorithm,
                'runs': len(per_run),
                'episodes': int(np.mean([len(r['return']) for r in per_run])),
                'advice_given': stat([r['advice_given'].sum() for r in per_run]),
                'advice_asked': stat([r['advice_asked'].sum() for r in per_run]),
                'final_return': stat([r['return'][-k:].mean() for r, k in zip(per_run, tail)]),
                'final_success': stat([r['success'][-k:].mean() for r, k in zip(per_run, tail)]),
                'success': stat([r['success'].mean() for r in per_run]),
                'episodes_to_threshold': stat(reached) if reached else (math.nan, math.nan),
                'reached': len(reached),
            }
        )
    return table


def format_table(table: list[dict], threshold: float) -> str:
    def pm(pair, digits=1, percent=False):
        mean, std = pair
        if math.isnan(mean):
            return '—'
        if math.isnan(std):  # one run
            return f'{100 * mean:.{digits}f} %' if percent else f'{mean:.{digits}f}'
        if percent:
            return f'{100 * mean:.{digits}f} ± {100 * std:.{digits}f} %'
        return f'{mean:.{digits}f} ± {std:.{digits}f}'

    lines = [
        f'| algorithm | runs | episodes | advice given | advice asked | final return (last 10%) | '
        f'success (last 10%) | success (all) | episodes to return ≥ {threshold:g} |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    for row in table:
        reach = pm(row['episodes_to_threshold'], 0)
        if row['reached'] < row['runs']:
            reach += f' ({row["reached"]} of {row["runs"]} runs reached it)'
        lines.append(
            f'| {LABELS.get(row["algorithm"], row["algorithm"])} | {row["runs"]} | {row["episodes"]} | '
            f'{pm(row["advice_given"], 0)} | {pm(row["advice_asked"], 0)} | {pm(row["final_return"])} | '
            f'{pm(row["final_success"], 0, True)} | {pm(row["success"], 0, True)} | {reach} |'
        )
    return '\n'.join(lines)


def _by_algorithm(runs, column):
    grouped = defaultdict(list)
    for (algorithm, _), run in sorted(runs.items()):
        grouped[algorithm].append(run[column])
    out = {}
    for algorithm, series in grouped.items():
        n = min(len(s) for s in series)
        out[algorithm] = np.stack([s[:n] for s in series])
    return dict(sorted(out.items(), key=lambda kv: ORDER.index(kv[0]) if kv[0] in ORDER else 99))


def read_eval(folders) -> dict[str, dict[int, list[float]]]:
    """{algorithm: {after episode: [per-seed mean return over the start states]}} from the
    folders' eval.csv (the advice-free evaluation); empty where there is none."""
    per_run = defaultdict(list)  # (algorithm, seed, episode) -> returns over start states
    for folder in folders:
        path = Path(folder) / 'eval.csv'
        if not path.exists():
            continue
        with path.open(newline='') as f:
            reader = csv.DictReader(f)
            for row in reader:
                _check_numbers(row, path, reader.line_num, ('episode', 'return'))
                per_run[(row['algorithm'], int(row['seed']), int(row['episode']))].append(float(row['return']))
    out = defaultdict(lambda: defaultdict(list))
    for (algorithm, _seed, episode), returns in sorted(per_run.items()):
        out[algorithm][episode].append(float(np.mean(returns)))
    return out


def eval_figure(evals, output: Path, env_id: str):
    """eval_returns.png: the advice-free return (each seed's mean over the fixed start states),
    mean and interquartile range over seeds, per algorithm."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for algorithm in sorted(evals, key=lambda a: ORDER.index(a) if a in ORDER else 99):
        episodes = sorted(evals[algorithm])
        values = [np.asarray(evals[algorithm][e]) for e in episodes]
        mean = [v.mean() for v in values]
        low, high = [np.percentile(v, 25) for v in values], [np.percentile(v, 75) for v in values]
        seeds = len(values[0])
        label = f'{LABELS.get(algorithm, algorithm)} ({seeds} seeds)'
        ax.plot(episodes, mean, marker='o', color=COLORS.get(algorithm), label=label)
        ax.fill_between(episodes, low, high, color=COLORS.get(algorithm), alpha=0.15)
    ax.set_xlabel('training episodes')
    ax.set_ylabel('return without advice (mean over seeds; band: IQR)')
    ax.set_title(f'{env_id}: the policy alone, deterministic, from fixed start states')
    ax.grid(alpha=0.3)
    ax.legend()
    path = output / 'eval_returns.png'
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def figures(runs, output: Path, env_id: str) -> list[Path]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    made = []

    def save(fig, name):
        path = output / name
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        made.append(path)

    for column, name, ylabel, smoothed in (
        ('return', 'returns.png', 'episode return', True),
        ('advice_given', 'advice.png', 'advice given per episode', False),
        ('success', 'success.png', 'success rate', True),
    ):
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for algorithm, data in _by_algorithm(runs, column).items():
            series = np.stack([smooth(row) for row in data]) if smoothed else data
            mean, std = series.mean(0), series.std(0)
            x = np.arange(len(mean))
            ax.plot(
                x, mean, color=COLORS.get(algorithm), label=f'{LABELS.get(algorithm, algorithm)} ({len(data)} seeds)'
            )
            ax.fill_between(x, mean - std, mean + std, color=COLORS.get(algorithm), alpha=0.15)
        ax.set_xlabel('episode')
        ax.set_ylabel(ylabel + (' (Savitzky-Golay, mean ± std over seeds)' if smoothed else ' (mean ± std)'))
        ax.set_title(f'{env_id}: {ylabel}')
        ax.grid(alpha=0.3)
        ax.legend()
        save(fig, name)

    advising = {k: v for k, v in runs.items() if k[0] != 'sac'}
    if advising:
        keys = sorted(advising, key=lambda k: (ORDER.index(k[0]) if k[0] in ORDER else 99, k[1]))
        n = min(len(advising[k]['advice_given']) for k in keys)
        used = max(
            (
                int(np.nonzero(advising[k]['advice_asked'][:n])[0].max()) + 1
                for k in keys
                if advising[k]['advice_asked'][:n].any()
            ),
            default=n,
        )
        matrix = np.stack([advising[k]['advice_given'][:used] for k in keys])
        fig, ax = plt.subplots(figsize=(9, 0.35 * len(keys) + 1.5))
        image = ax.imshow(matrix, aspect='auto', cmap='viridis', interpolation='nearest')
        ax.set_yticks(range(len(keys)), [f'{LABELS.get(a, a)} seed {s}' for a, s in keys])
        ax.set_xlabel('episode')
        ax.set_title(f'{env_id}: advice given per episode, each run')
        fig.colorbar(image, ax=ax, label='advice given')
        save(fig, 'advice_heatmap.png')
    return made
