"""A study's figures (matplotlib): evaluation curves, the performance profile, effort, the
frontier and a trace of the gates."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from ..core.experts.simulated_human import expected_seconds_per_request
from .stats import (
    iqm,
    performance_profile,
)
from .study_scores import frontier, per_seed, read_csv, sac_reference


def _pyplot():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def curve_arms(arms: list, group: str) -> list:
    """The arms a group's figure shows: its own, with the SAC arms and the matched arms they
    are measured against from other groups first."""
    shown = [a for a in arms if a.group == group]
    references = {sac_reference(a, arms) for a in shown if a.mode != 'sac'} | {a.match for a in shown if a.match}
    return [a for a in arms if a.name in references - {a.name for a in shown}] + shown


def plot_curves(arms: list, scores: dict, group: str, path: Path, threshold: float) -> None:
    """Evaluation return per arm of a group (and the arms it is measured against): IQM over
    seeds, with the band between the 25th and 75th percentiles."""
    plt = _pyplot()
    shown = curve_arms(arms, group)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for arm in shown:
        runs = [s.curve for (a, _), s in scores.items() if a == arm.name]
        if not runs:
            continue
        episodes = sorted(set.intersection(*(set(c) for c in runs)))
        values = np.array([[c[e] for e in episodes] for c in runs])
        line = ax.plot(episodes, iqm(values, axis=0), label=f'{arm.label} ({len(runs)} seeds)')[0]
        if len(runs) > 1:
            low, high = np.percentile(values, [25, 75], axis=0)
            ax.fill_between(episodes, low, high, color=line.get_color(), alpha=0.15)
    ax.axhline(threshold, color='black', linewidth=0.6, linestyle=':')
    ax.set_xlabel('training episodes before the evaluation')
    ax.set_ylabel('advice-free return (IQM over seeds)')
    ax.set_title(f'group {group}: the policy alone from fixed start states (band: 25th-75th percentile)')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_profile(arms: list, scores: dict, group: str, path: Path) -> None:
    """Performance profile of the final evaluation return: the fraction of runs above each score."""
    plt = _pyplot()
    shown = [a for a in arms if a.group == group]
    finals = {a.name: list(per_seed(scores, a.name, 'final').values()) for a in shown}
    values = [v for vs in finals.values() for v in vs]
    if not values:
        return
    taus = np.linspace(min(values) - 1, max(values) + 1, 200)
    fig, ax = plt.subplots(figsize=(6, 4))
    for arm in shown:
        if finals[arm.name]:
            ax.step(taus, performance_profile(finals[arm.name], taus), where='post', label=arm.label)
    ax.set_xlabel('final advice-free return τ')
    ax.set_ylabel('fraction of runs with return > τ')
    ax.set_title(f'performance profile, group {group}')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_effort(arms: list, scores: dict, path: Path) -> None:
    """Per run: requests (a person's effort) against the eval AUC gained over its SAC reference, same seed."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    by_mode = defaultdict(lambda: ([], []))
    for arm in arms:
        reference = sac_reference(arm, arms)
        if arm.mode == 'sac' or not reference:
            continue
        base = per_seed(scores, reference, 'auc')
        for seed, auc in per_seed(scores, arm.name, 'auc').items():
            if seed in base:
                xs, ys = by_mode[arm.mode]
                xs.append(scores[(arm.name, seed)].asked)
                ys.append(auc - base[seed])
    for mode, (xs, ys) in sorted(by_mode.items()):
        ax.scatter(xs, ys, s=14, alpha=0.7, label=f'{mode} ({len(xs)} runs)')
    ax.axhline(0.0, color='black', linewidth=0.6)
    ax.set_xscale('symlog', linthresh=10)
    ax.set_xlabel("requests to the expert in the run (a person's effort)")
    ax.set_ylabel('eval AUC minus SAC of the same seed')
    ax.set_title('what the requests bought (every arm and seed)')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_gates(folder: Path, path: Path, arm: str, seed: int, updates_from: int, around: int = 60) -> bool:
    """D(s) and E(s) with their queue thresholds around the first request after updates start
    (the first request of the run if none); requests marked."""
    gates = folder / 'gates.csv'
    if not gates.exists():
        return False
    rows = [r for r in read_csv(gates) if r['arm'] == arm and int(r['seed']) == seed]
    if not rows:
        return False
    fires = [i for i, r in enumerate(rows) if r['fire'] == '1']
    if not fires:
        return False
    late = [i for i in fires if int(rows[i]['episode']) >= updates_from]
    centre = (late or fires)[0]
    window = rows[max(0, centre - around) : centre + around]
    x = np.arange(len(window)) + max(0, centre - around)
    plt = _pyplot()
    fig, (ax_d, ax_e) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    column = {
        k: np.array([float(r[k]) for r in window]) for k in ('discrepancy', 'd_threshold', 'entropy', 'e_threshold')
    }
    fire = np.array([r['fire'] == '1' for r in window])
    ask = np.array([r['ask'] == '1' for r in window])
    ax_d.plot(x, column['discrepancy'], color='tab:red', label='D(s) = |Q1 - Q2| (Eq. 8)')
    ax_d.plot(x, column['d_threshold'], color='black', linewidth=0.8, linestyle='--', label='max(D_queue)')
    ax_d.scatter(
        x[ask & ~fire],
        column['discrepancy'][ask & ~fire],
        color='tab:orange',
        s=18,
        zorder=3,
        label='ask gate open, respond closed',
    )
    ax_d.scatter(x[fire], column['discrepancy'][fire], color='tab:green', s=30, zorder=4, label='both: a request')
    ax_e.plot(x, column['entropy'], color='tab:blue', label='E(s) (Eq. 9)')
    ax_e.plot(x, column['e_threshold'], color='black', linewidth=0.8, linestyle='--', label='min(E_queue)')
    ax_e.scatter(x[fire], column['entropy'][fire], color='tab:green', s=30, zorder=4, label='a request')
    first, last = window[0], window[-1]
    ax_e.set_xlabel(
        f'step inside the budget (episode {first["episode"]} step {first["step"]} to '
        f'episode {last["episode"]} step {last["step"]})'
    )
    ax_d.set_ylabel('critic disagreement')
    ax_e.set_ylabel('policy entropy')
    ax_d.legend(fontsize=7, loc='upper right')
    ax_e.legend(fontsize=7, loc='upper right')
    ax_d.set_title(f'inside the gates: {arm}, seed {seed}')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_frontier(arms: list, scores: dict, path: Path) -> bool:
    """AUC gain over SAC against requests (and a simulated person's seconds): the random arms at
    fixed rates drawn as a line, every other advising arm placed on it with its 95 % t interval."""
    line, placed = frontier(arms, scores)
    if len(line) < 2:
        return False
    plt = _pyplot()
    from ..core.algorithm.config import MODE_COLORS

    seconds = expected_seconds_per_request()
    fig, ax = plt.subplots(figsize=(8, 5))
    xs = [p.requests for p in line]
    ax.plot(xs, [p.gain for p in line], color='tab:green', marker='o', label='random requests at fixed rates')
    ax.fill_between(xs, [p.low for p in line], [p.high for p in line], color='tab:green', alpha=0.15)
    markers = 'sD^vP*Xh<>'
    for i, p in enumerate(placed):
        ax.errorbar(
            [p.requests], [p.gain], yerr=[[p.gain - p.low], [p.high - p.gain]], fmt=markers[i % len(markers)],
            color=MODE_COLORS.get(p.arm.mode, 'black'), capsize=3, label=p.arm.label,
        )  # fmt: skip
    ax.axhline(0.0, color='black', linewidth=0.6)
    ax.set_xscale('log')
    ax.set_xlabel('requests to the expert per run (mean over seeds)')
    ax.set_ylabel('eval AUC minus SAC of the same seed (mean, 95 % t)')
    top = ax.secondary_xaxis('top', functions=(lambda r: r * seconds, lambda t: t / seconds))
    top.set_xlabel(f"a simulated person's seconds ({seconds:.2f} s per request)")
    ax.set_title('the effort frontier: above the line is better than chance per request', fontsize=10)
    ax.legend(fontsize=7, loc='best')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
