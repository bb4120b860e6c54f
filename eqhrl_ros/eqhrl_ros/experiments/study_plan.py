"""A study's plan: its arms (a mode, learner settings, an expert, what it is matched to) in
groups of seeds, read from a YAML file (eqhrl-study's docstring has the format), and each arm's
run settings.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from ..core.algorithm.config import MODES
from ..files.paths import shared_file
from ..files.yaml_files import load_mapping
from .settings import Settings, learner_config, load_settings, make_expert

PLAN_KEYS = {
    'name',
    'description',
    'params',
    'episodes',
    'max_steps',
    'eval_every',
    'eval_starts',
    'learner',
    'groups',
    'tests',
}
GROUP_KEYS = {'name', 'seeds', 'arms', 'description'}
ARM_KEYS = {'mode', 'learner', 'expert', 'match', 'match_timing', 'thins', 'gate_trace', 'label'}
MATCH_TIMINGS = ('rate', 'episode', 'steps')


@dataclass
class Arm:
    name: str
    group: str
    mode: str
    seeds: list
    learner: dict = field(default_factory=dict)
    expert: dict = field(default_factory=dict)
    match: str = ''
    # mode random: 'rate' (requests per step), 'episode' (per-episode counts) or 'steps' (the
    # matched run's requests in each episode, moved by a random offset: random_ask_steps)
    match_timing: str = 'rate'
    thins: str = ''  # mode ask_random: the rate is match's requests over this arm's
    gate_trace: bool = False
    label: str = ''  # how tables and figures name it (default: the arm's name)


@dataclass
class Plan:
    name: str
    params: str
    episodes: int
    max_steps: int | None
    eval_every: int
    eval_starts: int
    learner: dict
    arms: list  # of Arm, in priority order
    path: str = ''

    def arm(self, name: str) -> Arm:
        return next(a for a in self.arms if a.name == name)


def plan_file(name_or_path: str) -> Path:
    """A study plan by path, or by name from share/eqhrl_ros/studies."""
    return shared_file('studies', name_or_path, 'study plan')


def _refuse_unknown(where: str, given: dict, known: set) -> None:
    unknown = sorted(set(given) - known)
    if unknown:
        raise ValueError(f'{where}: unknown key(s) {unknown}; known: {sorted(known)}')


def _expect(where: str, value, kind, what: str):
    """``value`` if it is a ``kind`` (bools are not ints), else a one-line ValueError."""
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ValueError(f'{where} must be {what}, got {value!r:.60}')
    return value


def _check_seeds(where: str, seeds) -> None:
    for seed in _expect(f'{where}: seeds', seeds, list, 'a list of seeds'):
        if _expect(f'{where}: seed', seed, int, 'a whole number') < 0:
            raise ValueError(f'{where}: seeds must be >= 0, got {seed}')
        if seeds.count(seed) > 1:  # one run folder: its rows were gathered twice
            raise ValueError(f'{where}: seed {seed} appears twice')


def load_plan(name_or_path: str) -> Plan:
    """The plan, refused with the place of the first mistake in it."""
    path = plan_file(name_or_path)
    data = load_mapping(path, 'study plan')
    _refuse_unknown(str(path), data, PLAN_KEYS)
    if 'episodes' not in data or _expect(f'{path}: episodes', data['episodes'], int, 'a whole number') < 1:
        raise ValueError(f'{path}: episodes must be a whole number >= 1')
    for key in ('learner',):
        _expect(f'{path}: {key}', data.get(key) or {}, dict, 'a mapping')
    arms = []
    for group in _expect(f'{path}: groups', data.get('groups') or [], list, 'a list of groups'):
        _expect(f'{path}: each group', group, dict, 'a mapping with name, seeds and arms')
        _refuse_unknown(f'{path}: group {group.get("name")!r}', group, GROUP_KEYS)
        where = f'{path}: group {group.get("name")!r}'
        _expect(f'{where}: name', group.get('name'), str, 'a name')
        _check_seeds(where, group.get('seeds'))
        for name, spec in _expect(f'{where}: arms', group.get('arms') or {}, dict, 'a mapping of arms').items():
            spec = _expect(f'{path}: arm {name!r}', spec or {}, dict, 'a mapping')
            _refuse_unknown(f'{path}: arm {name!r}', spec, ARM_KEYS)
            for key in ('learner', 'expert'):
                _expect(f'{path}: arm {name!r}: {key}', spec.get(key) or {}, dict, 'a mapping')
            if spec.get('mode') not in MODES:
                raise ValueError(f'{path}: arm {name!r}: mode must be one of {MODES}, got {spec.get("mode")!r}')
            if any(a.name == name for a in arms):
                raise ValueError(f'{path}: arm {name!r} appears twice')
            arms.append(
                Arm(
                    name=name,
                    group=group['name'],
                    mode=spec['mode'],
                    seeds=[int(s) for s in group['seeds']],
                    learner=dict(spec.get('learner') or {}),
                    expert=dict(spec.get('expert') or {}),
                    match=spec.get('match', ''),
                    match_timing=spec.get('match_timing', 'rate'),
                    thins=spec.get('thins', ''),
                    gate_trace=bool(spec.get('gate_trace', False)),
                    label=spec.get('label', name),
                )
            )
    if not arms:
        raise ValueError(f'{path}: no arms')
    names = {a.name for a in arms}
    for arm in arms:
        if arm.match_timing not in MATCH_TIMINGS:
            raise ValueError(f'{path}: arm {arm.name!r}: match_timing must be one of {MATCH_TIMINGS}')
        if arm.mode == 'ask_random' and not (arm.match and arm.thins):
            raise ValueError(f'{path}: arm {arm.name!r}: mode ask_random needs match and thins')
        if arm.thins and arm.mode != 'ask_random':
            raise ValueError(f'{path}: arm {arm.name!r}: thins is for mode ask_random')
        if arm.match_timing != 'rate' and arm.mode != 'random':
            raise ValueError(f'{path}: arm {arm.name!r}: match_timing is for mode random')
        if arm.match_timing == 'steps' and not any(a.name == arm.match and a.gate_trace for a in arms):
            raise ValueError(
                f'{path}: arm {arm.name!r}: match_timing steps reads the steps {arm.match!r} asked at from its '
                'gates.csv: give that arm gate_trace: true'
            )
        for key, other in (('match', arm.match), ('thins', arm.thins)):
            if not other:
                continue
            if arm.mode not in ('random', 'ask_random'):
                raise ValueError(f'{path}: arm {arm.name!r}: {key} is for modes random and ask_random')
            if other not in names:
                raise ValueError(f'{path}: arm {arm.name!r} {key} {other!r}, which is not an arm')
            missing = sorted(set(arm.seeds) - set(next(a for a in arms if a.name == other).seeds))
            if missing:
                raise ValueError(f'{path}: arm {arm.name!r} has seeds {missing} that {other!r} does not run')
    return Plan(
        name=data.get('name', path.stem),
        params=data.get('params', 'pendulum'),
        episodes=int(data['episodes']),
        max_steps=data.get('max_steps'),
        eval_every=int(data.get('eval_every', 10)),
        eval_starts=int(data.get('eval_starts', 10)),
        learner=dict(data.get('learner') or {}),
        arms=arms,
        path=str(path),
    )


def arm_settings(plan: Plan, arm: Arm, save_every: float | None = None) -> Settings:
    """The experiment runner's settings for one arm, checked as the runner checks a params file.
    ``save_every``: --save-every (minutes; None: the runner's default)."""
    args = argparse.Namespace(
        params=plan.params,
        # The env an arm's or the plan's learner settings name (before, an env_id there was ignored
        # and the params file's env ran).
        env=arm.learner.get('env_id') or plan.learner.get('env_id') or None,
        episodes=plan.episodes,
        max_steps=plan.max_steps,
        budget=None,
        expert=None,
        policy_path=None,
        through_ros=False,
        env_node=None,
        eval_every=plan.eval_every,
        eval_starts=plan.eval_starts,
        save_every=save_every,
    )
    settings = load_settings(args)
    learner = {**settings.learner, **plan.learner, **arm.learner}
    settings = dataclasses.replace(settings, learner=learner, expert_options=arm.expert, gate_trace=arm.gate_trace)
    learner_config(settings, arm.mode, 0)  # refuses a bad learner setting now, not in a worker
    make_expert(settings)
    return settings


def budget_of(settings: Settings) -> int:
    return int(learner_config(settings, 'sac', 0).advising_budget)


def run_list(plan: Plan) -> list:
    """(arm, seed) in the order they run: group by group, seed by seed, arm by arm."""
    order = []
    for group in dict.fromkeys(a.group for a in plan.arms):
        arms = [a for a in plan.arms if a.group == group]
        for seed in sorted({s for a in arms for s in a.seeds}):
            order += [(a, seed) for a in arms if seed in a.seeds]
    return order
