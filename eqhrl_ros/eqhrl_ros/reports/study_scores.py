"""A study's runs scored: each run's final, AUC, episodes to threshold and the advice it
asked for, read from the gathered CSVs; the comparisons between arms; the effort frontier."""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import yaml

from .stats import (
    sign_flip_p,
    t_interval,
)

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
    """A study's table, each row whole: ValueError names the file and line of one with fewer or more
    values than the header (a row torn by a kill, a hand edit). Before, a traceback further on."""
    with path.open(newline='') as f:
        reader = csv.DictReader(f)
        rows = []
        for row in reader:
            if None in row or None in row.values():
                raise ValueError(f'{path}, line {reader.line_num}: not one value for each of its columns')
            rows.append(row)
        return rows


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
    from ..files.mcap_record import RecordError, load_prior

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
    'random_ask_schedule',
    'random_ask_steps',
    'request_refractory_steps',
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


def frontier_arms(arms: list) -> list:
    """The effort frontier of chance: random arms asking at a fixed rate per budget step (no
    schedule matched to another arm), each with a SAC reference."""
    return [
        a
        for a in arms
        if a.mode == 'random' and not a.match and a.learner.get('random_ask_rate') and sac_reference(a, arms)
    ]


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
