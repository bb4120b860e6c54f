"""A study's report: table.md and the figures, from the output of eqhrl-study (what each
holds: eqhrl-study-report's docstring)."""

from __future__ import annotations

import shutil
import sys
from collections import defaultdict
from pathlib import Path

from ..experiments.settings import learner_config
from ..experiments.study_plan import arm_settings, budget_of, load_plan
from ..files.yaml_files import load_mapping
from .run_report import return_threshold
from .study_figures import plot_curves, plot_effort, plot_frontier, plot_gates, plot_profile
from .study_scores import RAW_FILES, first_update_episode, prior_size, read_arms, score_runs
from .study_tables import (
    arm_table,
    budget_table,
    comparison_table,
    frontier_table,
    gate_rates,
    person_table,
    placement_table,
    stated_tests,
    timing_table,
)


def write_report(folder: Path, output: Path, threshold=None) -> None:
    """table.md and the figures of the study in ``folder``, into ``output`` (the gathered CSVs
    copied beside them); ``threshold``: the return to reach (None: the env's, THRESHOLDS)."""
    plan = load_mapping(folder / 'plan.yaml', 'study plan')
    loaded = load_plan(str(folder / 'plan.yaml'))
    settings = {arm.name: arm_settings(loaded, arm) for arm in loaded.arms}
    env_id = next(iter(settings.values())).env_id
    threshold = return_threshold(
        env_id, threshold, say=lambda line: print(f'eqhrl-study-report: {line}', file=sys.stderr)
    )
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

    sections = report_sections(
        folder, output, plan, env_id, threshold, arms, scores, short, updates_from, budget, configs
    )
    (output / 'table.md').write_text('\n'.join(sections) + '\n')
    groups = list(dict.fromkeys(a.group for a in arms))
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


def report_sections(
    folder, output, plan, env_id, threshold, arms, scores, short, updates_from, budget, configs
) -> list:
    """table.md's lines, section by section."""
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
    placement = placement_table(folder, arms)
    if placement:
        sections += ['', '## Where the matched arms asked, beside the runs they are matched to', '', placement]
    rates = gate_rates(folder, updates_from, {name: c.queue_length for name, c in configs.items()})
    if rates:
        sections += ['', '## How often the gates opened inside the budget', '', rates]
    return sections
