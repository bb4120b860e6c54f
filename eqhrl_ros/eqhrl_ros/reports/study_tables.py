"""A study's tables (Markdown) from its scores: the arms, the same-seed differences, the
pre-stated tests, the timing of requests, the person's effort and the frontier."""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..core.experts.simulated_human import expected_seconds_per_request
from .stats import (
    holm,
    iqm,
    iqm_estimate,
    paired_difference,
    paired_test,
)
from .study_scores import comparisons, frontier, gains_over_sac, per_seed, read_csv


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


def clustered_share(steps_by_episode: dict, within: int = 2) -> float:
    """The share of requests with another request of the same episode at most ``within`` steps away."""
    near = total = 0
    for steps in steps_by_episode.values():
        ordered = sorted(steps)
        for i, step in enumerate(ordered):
            total += 1
            near += (i > 0 and step - ordered[i - 1] <= within) or (
                i + 1 < len(ordered) and ordered[i + 1] - step <= within
            )
    return near / total if total else float('nan')


def placement_table(folder: Path, arms: list) -> str:
    """Whether each matched arm asked where its reference's placement says (both with a gate
    trace): requests in all, the episodes whose counts agree, and the clustering of requests
    (the share within 2 steps of another) of the reference and of the matched arm."""
    if not (folder / 'gates.csv').exists():
        return ''
    fired: dict = defaultdict(lambda: defaultdict(list))  # (arm, seed) -> episode -> steps asked at
    for row in read_csv(folder / 'gates.csv'):
        runs = fired[(row['arm'], int(row['seed']))]
        runs.setdefault(int(row['episode']), [])
        if int(float(row['fire'])):
            runs[int(row['episode'])].append(int(row['step']))
    lines = [
        '| arm | matched to | seeds | requests (arm / reference) | episodes with the same count '
        '| within 2 steps of another: reference | arm |',
        '|---|---|---|---|---|---|---|',
    ]
    for arm in arms:
        seeds = sorted(s for a, s in fired if a == arm.name and (arm.match, s) in fired) if arm.match else []
        if not seeds:
            continue
        ours = {s: fired[(arm.name, s)] for s in seeds}
        theirs = {s: fired[(arm.match, s)] for s in seeds}
        same = sum(len(ours[s].get(e, [])) == len(steps) for s in seeds for e, steps in theirs[s].items())
        episodes = sum(len(theirs[s]) for s in seeds)
        asked = sum(len(v) for s in seeds for v in ours[s].values())
        reference = sum(len(v) for s in seeds for v in theirs[s].values())
        ref_share = clustered_share({(s, e): v for s in seeds for e, v in theirs[s].items()})
        arm_share = clustered_share({(s, e): v for s in seeds for e, v in ours[s].items()})
        lines.append(
            f'| {arm.label} | {arm.match} | {len(seeds)} | {asked} / {reference} | {same} of {episodes} '
            f'| {100 * ref_share:.0f} % | {100 * arm_share:.0f} % |'
        )
    return '\n'.join(lines) if len(lines) > 2 else ''
