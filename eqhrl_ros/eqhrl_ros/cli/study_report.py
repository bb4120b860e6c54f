"""eqhrl-study-report: the tables and figures of a study made by eqhrl-study.

    eqhrl-study-report runs/study_pendulum --output docs/results/study_pendulum

Everything is measured on the advice-free evaluation (eval.csv: the deterministic policy
alone from fixed start states every few episodes), never on training returns, which mix
the learner's actions with the expert's inside the budget. Per run:

- final: the mean evaluation return after the last episode;
- AUC: the mean evaluation return over all evaluations (the area under the evaluation
  curve divided by its length): how good the policy was along the way;
- episodes to threshold: the first evaluation whose mean reaches the env's threshold
  (report.THRESHOLDS; runs that never do are counted apart);
- requests: the advice the learner asked for (a person's effort), and advice given.

Per arm, the interquartile mean (IQM) over seeds with a 95 % bootstrap interval. Between
arms, the same-seed differences (the runner pairs seeds) with a 95 % bootstrap interval and
how many seeds the first arm won. Each advising arm is compared with plain SAC of the same
settings (the first SAC arm whose learner settings are the same, leaving out those SAC never
reads, such as the budget), and with the random-request arm matched to it, where there is
one. Where the plan has random arms at fixed rates (at least two), every other advising arm is
placed on their effort frontier: its gain over SAC minus chance's at the same request count.
Writes table.md, eval_<group>.png, profile.png, effort.png, frontier.png and gates.png into --output,
and copies the gathered CSVs beside them.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import shutil
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import yaml

from ..core.experts.simulated_human import expected_seconds_per_request
from ..stats import (
    holm,
    iqm,
    iqm_estimate,
    paired_difference,
    paired_test,
    performance_profile,
    sign_flip_p,
    t_interval,
)
from ..yaml_files import load_mapping
from .report import THRESHOLDS

RAW_FILES = ('arms.csv', 'episodes.csv', 'eval.csv', 'gates.csv', 'plan.yaml')


@dataclass
class ArmInfo:
    name: str
    label: str
    group: str
    mode: str
    match: str
    learner: dict = field(default_factory=dict)


@dataclass
class RunScores:
    final: float
    auc: float
    to_threshold: float  # NaN: never reached
    asked: int
    given: int
    budget_return: float  # training return inside the budget (learner and expert mixed)
    curve: dict  # {episode: mean evaluation return}
    success_final: float = math.nan  # share of the last evaluation's start states that succeeded
    success_mean: float = math.nan  # the same over every evaluation
    taken_over: int = 0  # steps a (simulated) person took over unasked
    person_s: float = 0.0  # the person's seconds: answering requests and taking over


def read_csv(path: Path) -> list[dict]:
    with path.open(newline='') as f:
        return list(csv.DictReader(f))


def read_arms(folder: Path) -> list[ArmInfo]:
    return [
        ArmInfo(r['arm'], r['label'] or r['arm'], r['group'], r['mode'], r['match'], yaml.safe_load(r['learner']) or {})
        for r in read_csv(folder / 'arms.csv')
    ]


def score_runs(folder: Path, threshold: float, budget: dict) -> dict:
    """{(arm, seed): RunScores} for every run with an evaluation."""
    curves = defaultdict(lambda: defaultdict(list))
    successes = defaultdict(lambda: defaultdict(list))
    for row in read_csv(folder / 'eval.csv'):
        curves[(row['arm'], int(row['seed']))][int(row['episode'])].append(float(row['return']))
        if row.get('success', '') != '':
            successes[(row['arm'], int(row['seed']))][int(row['episode'])].append(float(row['success']))
    training = defaultdict(list)
    for row in read_csv(folder / 'episodes.csv'):
        training[(row['arm'], int(row['seed']))].append(row)
    scores = {}
    for key, by_episode in curves.items():
        episodes = sorted(by_episode)
        means = [float(np.mean(by_episode[e])) for e in episodes]
        reached = [e for e, m in zip(episodes, means) if m >= threshold]
        rows = training.get(key, [])
        inside = [float(r['return']) for r in rows if int(r['episode']) < budget.get(key[0], 0)]
        scores[key] = RunScores(
            final=means[-1],
            auc=float(np.mean(means)),
            to_threshold=float(reached[0]) if reached else math.nan,
            asked=sum(int(r['advice_asked']) for r in rows),
            given=sum(int(r['advice_given']) for r in rows),
            budget_return=float(np.mean(inside)) if inside else math.nan,
            curve=dict(zip(episodes, means)),
            success_final=float(np.mean(successes[key][episodes[-1]])) if successes[key] else math.nan,
            success_mean=float(np.mean([np.mean(v) for v in successes[key].values()])) if successes[key] else math.nan,
            taken_over=sum(int(r.get('takeover_steps') or 0) for r in rows),
            person_s=sum(float(r.get('human_time_s') or 0) + float(r.get('takeover_s') or 0) for r in rows),
        )
    return scores


def prior_size(settings) -> int:
    """Transitions an arm's runs start D with (its learner's prior; 0 without, or when unreadable)."""
    sources = settings.learner.get('prior') or []
    if not sources:
        return 0
    from ..core import make_env
    from ..mcap_record import RecordError, load_prior

    env = make_env(settings.env_id, settings.max_episode_steps)
    try:
        return len(
            load_prior(sources, int(env.observation_space.shape[0]), env.action_space.low, env.action_space.high)
        )
    except RecordError:
        return 0
    finally:
        env.close()


def first_update_episode(folder: Path, learning_starts: dict) -> dict:
    """{(arm, seed): the first episode in which updates ran}: the episode holding the
    learning_starts-th transition, from the run's episode lengths (LunarLander's vary)."""
    lengths = defaultdict(list)
    for row in read_csv(folder / 'episodes.csv'):
        lengths[(row['arm'], int(row['seed']))].append((int(row['episode']), int(row['length'])))
    first = {}
    for key, rows in lengths.items():
        steps = 0
        for episode, length in sorted(rows):
            steps += length
            if steps >= learning_starts.get(key[0], 0):
                first[key] = episode
                break
    return first


def timing_table(folder: Path, arms: list, updates_from: dict, budget: dict) -> str:
    """When each arm asked: requests inside the budget before the first update and after."""
    asked = defaultdict(lambda: [0, 0])
    for row in read_csv(folder / 'episodes.csv'):
        key = (row['arm'], int(row['seed']))
        if key not in updates_from or int(row['episode']) >= budget.get(row['arm'], 0):
            continue
        asked[key][int(row['episode']) >= updates_from[key]] += int(row['advice_asked'])
    lines = [
        '| arm | seeds | first episode with updates (range) | requests before updates | after | share before |',
        '|---|---|---|---|---|---|',
    ]
    for arm in arms:
        keys = [k for k in asked if k[0] == arm.name]
        before, after = sum(asked[k][0] for k in keys), sum(asked[k][1] for k in keys)
        if not keys or before + after == 0:
            continue
        starts = [updates_from[k] for k in keys]
        lines.append(
            f'| {arm.label} | {len(keys)} | {min(starts)}–{max(starts)} | {before} | {after} '
            f'| {100 * before / (before + after):.0f} % |'
        )
    return '\n'.join(lines)


def _p(p: float) -> str:
    return '<0.001' if p < 0.001 else f'{p:.3f}'


def stated_tests(tests: dict, arms: list, scores: dict) -> str:
    """The plan's pre-stated comparisons: primary ones Holm-corrected together, secondary ones not."""
    labels = {a.name: a.label for a in arms}
    metric, margin = tests.get('metric', 'auc'), float(tests.get('margin', 5.0))
    lines = [
        f'Metric: {metric}; margin of equivalence ±{margin:g}; 95 % t intervals; p: two-sided sign-flip '
        'permutation test of the same-seed differences; Holm over the primary family; TOST: two one-sided t '
        'tests at 5 % (equivalent when below 0.05). Verdict: different (p, Holm-corrected for primary rows, below '
        '0.05), equivalent (TOST below 0.05), else unresolved.',
        '',
        '| family | comparison | seeds | Δ mean [95 % t] | p | Holm p | TOST p | verdict |',
        '|---|---|---|---|---|---|---|---|',
    ]
    for family in ('primary', 'secondary'):
        pairs = [p for p in tests.get(family) or [] if p[0] in labels and p[1] in labels]
        results = [
            paired_test(per_seed(scores, a, metric), per_seed(scores, b, metric), margin, seed=i)
            for i, (a, b) in enumerate(pairs)
        ]
        kept = [(p, r) for p, r in zip(pairs, results) if r.n >= 2]
        if family == 'primary' and kept:
            adjusted = holm([r.p for _, r in kept])
            kept = [(p, dataclasses.replace(r, holm=h)) for (p, r), h in zip(kept, adjusted)]
        for (a, b), r in kept:
            holm_text = _p(r.holm) if not math.isnan(r.holm) else '—'
            lines.append(
                f'| {family} | {labels[a]} − {labels[b]} | {r.n} | {r.mean:+.1f} [{r.low:+.1f}, {r.high:+.1f}] '
                f'| {_p(r.p)} | {holm_text} | {_p(r.tost_p)} | {r.verdict()} |'
            )
    return '\n'.join(lines)


def per_seed(scores: dict, arm: str, metric: str) -> dict:
    return {seed: getattr(s, metric) for (a, seed), s in scores.items() if a == arm}


# Learner settings that plain SAC never reads: arms that differ only in these share a SAC reference.
ADVISING_ONLY = {
    'advising_budget',
    'queue_length',
    'random_ask_rate',
    'dual_replay',
    'advice_batch',
    'actor_on_advice',
    'entropy_estimator',
    'entropy_samples',
    'threshold_kind',
    'fixed_d_threshold',
    'fixed_e_threshold',
}


def sac_reference(arm: ArmInfo, arms: list) -> str:
    """The SAC arm an advising arm is measured against: the first one whose learner settings
    are the arm's, leaving out those SAC never reads ('' if there is none)."""

    def learning(a: ArmInfo) -> dict:
        return {k: v for k, v in a.learner.items() if k not in ADVISING_ONLY}

    same = [a for a in arms if a.mode == 'sac' and learning(a) == learning(arm)]
    return same[0].name if same else ''


def comparisons(arms: list) -> list[tuple[str, str, str]]:
    """(arm, versus, why) pairs the report shows."""
    pairs = []
    for arm in arms:
        if arm.mode == 'sac':
            continue
        reference = sac_reference(arm, arms)
        if reference:
            pairs.append((arm.name, reference, 'vs SAC'))
        for other in arms:
            if other.match == arm.name:
                pairs.append((arm.name, other.name, 'vs random, matched'))
    return pairs


def arm_table(arms: list, scores: dict, threshold: float) -> str:
    lines = [
        '| arm | group | seeds | requests (IQM) | final eval return (IQM [95% CI]) | eval AUC (IQM [95% CI]) '
        f'| episodes to eval ≥ {threshold:g} (IQM of runs that reach it) | reached | final eval success '
        '| eval success over the run |',
        '|---|---|---|---|---|---|---|---|---|---|',
    ]
    for arm in arms:
        seeds = sorted(per_seed(scores, arm.name, 'final'))
        if not seeds:
            continue
        reach = [v for v in per_seed(scores, arm.name, 'to_threshold').values() if not math.isnan(v)]
        asked = list(per_seed(scores, arm.name, 'asked').values())
        lines.append(
            f'| {arm.label} | {arm.group} | {len(seeds)} | {float(iqm(asked)):.0f} '
            f'| {iqm_estimate(list(per_seed(scores, arm.name, "final").values())).text()} '
            f'| {iqm_estimate(list(per_seed(scores, arm.name, "auc").values())).text()} '
            f'| {iqm_estimate(reach).text(0) if reach else "—"} | {len(reach)}/{len(seeds)} '
            f'| {_share(per_seed(scores, arm.name, "success_final"))} '
            f'| {_share(per_seed(scores, arm.name, "success_mean"))} |'
        )
    return '\n'.join(lines)


def _share(values: dict) -> str:
    kept = [v for v in values.values() if not math.isnan(v)]
    return f'{100 * float(np.mean(kept)):.0f} %' if kept else '—'


def comparison_table(arms: list, scores: dict) -> str:
    labels = {a.name: a.label for a in arms}
    lines = [
        '| arm | versus | seeds | Δ final eval return (mean [95% CI]) | wins | Δ eval AUC (mean [95% CI]) | wins '
        '| Δ requests (mean) |',
        '|---|---|---|---|---|---|---|---|',
    ]
    for arm, versus, _ in comparisons(arms):
        final, final_wins, n = paired_difference(
            per_seed(scores, arm, 'final'), per_seed(scores, versus, 'final'), seed=1
        )
        if n == 0:
            continue
        auc, auc_wins, _ = paired_difference(per_seed(scores, arm, 'auc'), per_seed(scores, versus, 'auc'), seed=2)
        asked, _, _ = paired_difference(per_seed(scores, arm, 'asked'), per_seed(scores, versus, 'asked'), seed=3)
        lines.append(
            f'| {labels[arm]} | {labels[versus]} | {n} | {final.text()} | {final_wins}/{n} | {auc.text()} '
            f'| {auc_wins}/{n} | {asked.value:+.0f} |'
        )
    return '\n'.join(lines)


def person_table(arms: list, scores: dict) -> str:
    """What each arm cost the person, measured (requests answered and steps taken over, in their
    seconds), beside what it bought; '' when no arm had a person."""
    rows = []
    for arm in arms:
        person = list(per_seed(scores, arm.name, 'person_s').values())
        if not person:
            continue
        rows.append(
            f'| {arm.label} | {len(person)} | {np.mean(list(per_seed(scores, arm.name, "asked").values())):.0f} '
            f'| {np.mean(list(per_seed(scores, arm.name, "taken_over").values())):.0f} '
            f'| {np.mean(person):.1f} [{min(person):.1f}, {max(person):.1f}] '
            f'| {iqm_estimate(list(per_seed(scores, arm.name, "auc").values())).text()} |'
        )
    if not any(np.mean(list(per_seed(scores, a.name, 'person_s').values()) or [0]) > 0 for a in arms):
        return ''
    return '\n'.join(
        [
            '| arm | seeds | requests (mean) | steps taken over (mean) '
            "| the person's seconds, measured (mean [min, max]) | eval AUC (IQM [95% CI]) |",
            '|---|---|---|---|---|---|',
            *rows,
        ]
    )


def budget_table(arms: list, scores: dict) -> str:
    """Training returns inside the budget beside the evaluation: what the expert's actions add."""
    lines = [
        '| arm | training return inside the budget (IQM) | eval AUC (IQM) |',
        '|---|---|---|',
    ]
    for arm in arms:
        inside = [v for v in per_seed(scores, arm.name, 'budget_return').values() if not math.isnan(v)]
        auc = list(per_seed(scores, arm.name, 'auc').values())
        if inside and auc:
            lines.append(f'| {arm.label} | {float(iqm(inside)):.1f} | {float(iqm(auc)):.1f} |')
    return '\n'.join(lines)


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


def gate_rates(folder: Path, updates_from: dict, queue_length: dict) -> str:
    """How often each gate opened inside the budget once its queues were full, before and after
    updates start (``updates_from``: per run, the first episode with updates)."""
    gates = folder / 'gates.csv'
    if not gates.exists():
        return ''
    counts = defaultdict(lambda: np.zeros(4))
    seen = defaultdict(int)
    has_respond = set()  # arms with a respond gate (E(s) evaluated)
    per_run = defaultdict(lambda: np.zeros(4))  # (arm, when, seed) -> the same counts
    for r in read_csv(gates):
        run = (r['arm'], int(r['seed']))
        seen[run] += 1
        if seen[run] <= queue_length.get(r['arm'], 0):
            continue  # the queues hold fewer than queue_length earlier values: gates closed
        key = (r['arm'], 'before updates' if int(r['episode']) < updates_from.get(run, 0) else 'after updates')
        if r['entropy'] not in ('nan', ''):
            has_respond.add(r['arm'])
        step = (1, r['ask'] == '1', r['respond'] == '1', r['fire'] == '1')
        counts[key] += step
        per_run[(*key, run[1])] += step
    lines = [
        '| arm | steps with full queues | ask gate open | respond gate open | both (requests) | product of the two '
        '| lift per seed (both / product: min–max) |',
        '|---|---|---|---|---|---|---|',
    ]
    for (arm, when), (n, ask, respond, fire) in sorted(counts.items()):
        if arm not in has_respond:
            lines.append(f'| {arm}, {when} | {int(n)} | {100 * ask / n:.1f} % | — | {100 * fire / n:.2f} % | | |')
            continue
        lifts = [
            (f / m) / ((a / m) * (r / m))
            for (a_, w_, _), (m, a, r, f) in per_run.items()
            if (a_, w_) == (arm, when) and a and r
        ]
        lift = f'{min(lifts):.2f}–{max(lifts):.2f} ({len(lifts)} seeds)' if lifts else '—'
        lines.append(
            f'| {arm}, {when} | {int(n)} | {100 * ask / n:.1f} % | {100 * respond / n:.1f} % | {100 * fire / n:.2f} % '
            f'| {100 * (ask / n) * (respond / n):.2f} % | {lift} |'
        )
    return '\n'.join(lines)


def frontier_arms(arms: list) -> list:
    """The effort frontier of chance: random arms asking at a fixed rate per budget step (no
    schedule matched to another arm), each with a SAC reference."""
    return [
        a
        for a in arms
        if a.mode == 'random' and not a.match and a.learner.get('random_ask_rate') and sac_reference(a, arms)
    ]


def gains_over_sac(scores: dict, arm: ArmInfo, arms: list) -> dict:
    """{seed: eval AUC minus the SAC reference's of the same seed}."""
    base = per_seed(scores, sac_reference(arm, arms), 'auc')
    return {seed: auc - base[seed] for seed, auc in per_seed(scores, arm.name, 'auc').items() if seed in base}


@dataclass
class FrontierPoint:
    arm: ArmInfo
    requests: float  # mean over seeds
    gain: float  # mean AUC gain over SAC
    low: float  # its 95 % t interval
    high: float
    above: Optional[tuple] = None  # (n, mean, low, high, p) of the gain minus the frontier's, same seeds


def frontier(arms: list, scores: dict) -> tuple[list, list]:
    """(the frontier's points by requests, every advising arm placed against it). An arm is
    placed by seed: its gain minus the frontier's gain at the arm's mean request count, the
    frontier drawn through that seed's random arms (linear in log requests); arms asking
    fewer or more than every frontier arm are left unplaced."""

    def point(arm: ArmInfo) -> Optional[FrontierPoint]:
        gains = gains_over_sac(scores, arm, arms)
        if len(gains) < 2:
            return None
        requests = float(np.mean([scores[(arm.name, seed)].asked for seed in gains]))
        values = np.array(list(gains.values()))
        low, high = t_interval(values)
        return FrontierPoint(arm, requests, float(values.mean()), low, high)

    line = sorted((p for p in map(point, frontier_arms(arms)) if p), key=lambda p: p.requests)
    placed = []
    for arm in arms:
        if arm.mode == 'sac' or arm in [p.arm for p in line] or not sac_reference(arm, arms):
            continue
        placed_point = point(arm)
        if placed_point is None:
            continue
        if len(line) >= 2 and line[0].requests <= placed_point.requests <= line[-1].requests:
            x = math.log(max(placed_point.requests, 1e-9))
            xs = [math.log(max(p.requests, 1e-9)) for p in line]
            per_arm = [gains_over_sac(scores, p.arm, arms) for p in line]
            own = gains_over_sac(scores, arm, arms)
            seeds = sorted(set(own).intersection(*per_arm))
            diffs = np.array([own[s] - np.interp(x, xs, [g[s] for g in per_arm]) for s in seeds])
            if len(diffs) >= 2:
                low, high = t_interval(diffs)
                placed_point.above = (len(diffs), float(diffs.mean()), low, high, sign_flip_p(diffs, seed=7))
        placed.append(placed_point)
    return line, placed


def frontier_table(arms: list, scores: dict) -> str:
    line, placed = frontier(arms, scores)
    if len(line) < 2:
        return ''
    seconds = expected_seconds_per_request()
    lines = [
        f"A simulated person's seconds: requests × {seconds:.2f} s, the mean time the simulated person "
        '(simulated_human.HumanLimits defaults) spends on a request, misses included. Above the frontier: the '
        "arm's AUC gain over SAC minus the gain of random requests at the same count (interpolated in log requests "
        "through the same seed's frontier arms), with its 95 % t interval and sign-flip p.",
        '',
        "| arm | seeds | requests (mean) | person's seconds | Δ AUC over SAC (mean [95 % t]) | above the frontier "
        '(Δ [95 % t]) | p |',
        '|---|---|---|---|---|---|---|',
    ]
    for p in line + placed:
        above = (
            (f'{p.above[1]:+.1f} [{p.above[2]:+.1f}, {p.above[3]:+.1f}] ({p.above[0]} seeds)', _p(p.above[4]))
            if p.above
            else (('(the frontier)', '') if p in line else ('outside its range', ''))
        )
        seeds = len(gains_over_sac(scores, p.arm, arms))
        lines.append(
            f'| {p.arm.label} | {seeds} | {p.requests:.0f} | {p.requests * seconds:.0f} '
            f'| {p.gain:+.1f} [{p.low:+.1f}, {p.high:+.1f}] | {above[0]} | {above[1]} |'
        )
    return '\n'.join(lines)


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='eqhrl-study-report',
        description=__doc__.split('\n')[0],
        epilog=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument('folder', help='the output folder of eqhrl-study')
    parser.add_argument('--output', required=True, help='where the tables and figures go')
    parser.add_argument(
        '--overwrite', action='store_true', help='replace a table.md already in --output (e.g. committed results)'
    )
    parser.add_argument('--threshold', type=float, help="return threshold (default: the env's, report.THRESHOLDS)")
    args = parser.parse_args(argv)
    folder, output = Path(args.folder), Path(args.output)
    if (output / 'table.md').exists() and not args.overwrite:
        print(
            f'eqhrl-study-report: {output} holds a report already (table.md); give --overwrite to replace it',
            file=sys.stderr,
        )
        return 2
    for name in ('arms.csv', 'episodes.csv', 'eval.csv', 'plan.yaml'):
        if not (folder / name).exists():
            print(f'eqhrl-study-report: {folder / name} is missing (run eqhrl-study first)', file=sys.stderr)
            return 2
    plan = load_mapping(folder / 'plan.yaml', 'study plan')
    from ..experiments.settings import learner_config
    from .study import arm_settings, budget_of, load_plan

    loaded = load_plan(str(folder / 'plan.yaml'))
    settings = {arm.name: arm_settings(loaded, arm) for arm in loaded.arms}
    env_id = next(iter(settings.values())).env_id
    threshold = args.threshold if args.threshold is not None else THRESHOLDS.get(env_id, 0.0)
    budget = {name: budget_of(s) for name, s in settings.items()}
    configs = {arm.name: learner_config(settings[arm.name], arm.mode, 0) for arm in loaded.arms}
    # The first episode with updates, run by run (LunarLander's episodes end at other steps).
    # An arm seeded with prior data (its learner's prior) starts D with it: fewer steps to learning_starts.
    starts = {name: max(0, c.learning_starts - prior_size(settings[name])) for name, c in configs.items()}
    updates_from = first_update_episode(folder, starts)
    arms = read_arms(folder)
    scores = score_runs(folder, threshold, budget)
    planned = {arm.name: len(arm.seeds) for arm in loaded.arms}
    done = defaultdict(int)
    for arm_name, _ in scores:
        done[arm_name] += 1
    short = [f'{a} ({done[a]} of {n})' for a, n in planned.items() if done[a] < n]
    output.mkdir(parents=True, exist_ok=True)
    for name in RAW_FILES:
        if (folder / name).exists() and (folder / name).resolve() != (output / name).resolve():
            shutil.copyfile(folder / name, output / name)

    groups = list(dict.fromkeys(a.group for a in arms))
    sections = [
        f'# Study {plan.get("name", folder.name)}: {env_id}',
        '',
        f'Made by `eqhrl-study-report {folder} --output {output}`. Scores are advice-free evaluations '
        '(the policy alone from fixed start states). IQM: interquartile mean over seeds; [ ]: 95 % '
        'percentile bootstrap interval; Δ: same-seed difference, its mean and interval; wins: seeds '
        'where the first arm scored higher.',
        '',
        *([f'Not finished (seeds with an evaluation, of those planned): {", ".join(short)}.', ''] if short else []),
        *(['## Pre-stated tests', '', stated_tests(plan['tests'], arms, scores), ''] if plan.get('tests') else []),
        '## Arms',
        '',
        arm_table(arms, scores, threshold),
        '',
        '## Same-seed differences',
        '',
        comparison_table(arms, scores),
        '',
        '## Training returns inside the budget (learner and expert mixed) beside the evaluation',
        '',
        budget_table(arms, scores),
        '',
        '## When the arms asked: requests inside the budget before and after updates begin',
        '',
        timing_table(folder, arms, updates_from, budget),
    ]
    person = person_table(arms, scores)
    if person:
        sections += ['', '## What the person spent, measured: answering requests and taking over', '', person]
    placed = frontier_table(arms, scores)
    if placed:
        sections += ['', '## The effort frontier: each gate against random requests at the same count', '', placed]
    rates = gate_rates(folder, updates_from, {name: c.queue_length for name, c in configs.items()})
    if rates:
        sections += ['', '## How often the gates opened inside the budget', '', rates]
    (output / 'table.md').write_text('\n'.join(sections) + '\n')
    scored = {arm for arm, _ in scores}
    for group in groups:
        if any(a.group == group and a.name in scored for a in arms):
            plot_curves(arms, scores, group, output / f'eval_{group}.png', threshold)
    plot_profile(arms, scores, groups[0], output / 'profile.png')
    plot_effort(arms, scores, output / 'effort.png')
    plot_frontier(arms, scores, output / 'frontier.png')
    traced = [a.name for a in arms if a.mode == 'eqsac']
    if traced:  # the first seed of the first EQSAC arm that asked at all
        asked = sorted(seed for (arm, seed), s in scores.items() if arm == traced[0] and s.asked)
        if asked:
            plot_gates(folder, output / 'gates.png', traced[0], asked[0], updates_from.get((traced[0], asked[0]), 0))
    print(f'wrote {output / "table.md"} and figures')
    return 0


if __name__ == '__main__':
    sys.exit(main())
