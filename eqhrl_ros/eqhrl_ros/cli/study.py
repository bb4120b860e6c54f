"""eqhrl-study: a whole study (arms x seeds) in one resumable command.

    eqhrl-study --plan pendulum --output runs/study_pendulum --jobs 2
    eqhrl-study --plan pendulum --output runs/study_pendulum --list        # the size, nothing run
    eqhrl-study --plan pendulum --output runs/study_pendulum --groups main # a part of it

A plan (a YAML file, or the name of one in share/eqhrl_ros/studies) names a params file
(the env, Table 1, the expert), the episodes, the advice-free evaluation, learner settings
shared by every arm, and groups of arms in order of priority. An arm is a mode with its own
learner settings and expert:

    groups:
      - name: main
        seeds: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
        arms:
          eqsac: {mode: eqsac, gate_trace: true}
          random: {mode: random, match: eqsac}      # asks as often as eqsac did, seed by seed
          eqsac_noisy: {mode: eqsac, expert: {human: {action_noise: 0.3}}}

- ``learner``: learner parameters (the params file's names), over the plan's own.
- ``expert``: ``human`` (simulated_human.HumanLimits fields: a noisy hand, skipped and missed
  requests), ``delay_steps`` (the answer is for the state that many steps before),
  ``gain`` (a timid controller): core/experts/imperfect.py.
- ``match`` (mode random): the arm's random_ask_rate for seed k is the named arm's requests
  per step inside the budget in seed k; the run waits for that one to finish. With
  ``match_timing: episode``, the arm instead asks in each episode exactly as many times as the
  named arm did in that episode of seed k, at random steps of it (random_ask_schedule): matched
  in number and in timing.
- ``match`` and ``thins`` (mode ask_random): the arm's random_ask_rate for seed k is the
  ``match`` arm's requests over the ``thins`` arm's (e.g. EQSAC's over QASAC's): the ask gate
  thinned by chance to about the number of requests the entropy gate let through.
- ``gate_trace``: write gates.csv, D(s), E(s) and their thresholds at every step inside the budget.

Runs go group by group, seed by seed, so that a cut study still holds whole, paired seeds.
Each run writes <output>/<arm>/seed<k>/ (episodes.csv, eval.csv, gates.csv, DONE);
<output>/episodes.csv, eval.csv and gates.csv gather the finished runs (after each one) with
an ``arm`` column, and <output>/arms.csv says what each arm is. Interrupt with Ctrl-C and run the same
command again: finished runs are kept, unfinished ones continue from their last save (every
--save-every minutes, between episodes: core/runs/resume_point.py). eqhrl-study-report
turns the output into tables and figures.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import queue
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..core.algorithm.config import MODES
from ..experiments import gather as gathering
from ..experiments.run_pool import ClusterUnavailable, progress_queue, run_pool
from ..experiments.seed_runs import GATE_FIELDS, run_dir, run_worker
from ..experiments.settings import Settings, learner_config, load_settings, make_expert
from ..paths import shared_file
from ..yaml_files import load_mapping
from . import experiment

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
MATCH_TIMINGS = ('rate', 'episode')


@dataclass
class Arm:
    name: str
    group: str
    mode: str
    seeds: list
    learner: dict = field(default_factory=dict)
    expert: dict = field(default_factory=dict)
    match: str = ''
    match_timing: str = 'rate'  # mode random: 'rate' (requests per step) or 'episode' (per-episode counts)
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
        for seed in _expect(f'{where}: seeds', group.get('seeds'), list, 'a list of seeds'):
            if _expect(f'{where}: seed', seed, int, 'a whole number') < 0:
                raise ValueError(f'{where}: seeds must be >= 0, got {seed}')
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
        env=None,
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


def requests_per_episode(run: Path, budget: int) -> list[tuple[int, int]]:
    """(requests, steps) of each of the first ``budget`` episodes of a finished run, in order."""
    rows = {}
    with (run / 'episodes.csv').open(newline='') as f:
        for row in csv.DictReader(f):
            if int(row['episode']) < budget:
                rows[int(row['episode'])] = (int(row['advice_asked']), int(row['length']))
    return [rows.get(e, (0, 0)) for e in range(max(rows) + 1)] if rows else []


def matched_rate(run: Path, budget: int) -> tuple[float, int, int]:
    """(requests per step, requests, steps) inside the first ``budget`` episodes of a finished run."""
    episodes = requests_per_episode(run, budget)
    asked, steps = sum(a for a, _ in episodes), sum(n for _, n in episodes)
    return (asked / steps if steps else 0.0), asked, steps


def run_minutes(run: Path):
    """How long a finished run took: the seconds its DONE mark holds (a lone run's own time,
    earlier processes included), which survive a copy or a clone of the folder; for a mark
    without them, from its STARTED mark (a resumed run's last start) to DONE's time. None if
    neither tells."""
    try:
        return max(0.0, float((run / 'DONE').read_text().strip()) / 60)
    except (OSError, ValueError):
        pass
    try:
        return max(0.0, ((run / 'DONE').stat().st_mtime - (run / 'STARTED').stat().st_mtime) / 60)
    except OSError:
        return None


def run_list(plan: Plan) -> list:
    """(arm, seed) in the order they run: group by group, seed by seed, arm by arm."""
    order = []
    for group in dict.fromkeys(a.group for a in plan.arms):
        arms = [a for a in plan.arms if a.group == group]
        for seed in sorted({s for a in arms for s in a.seeds}):
            order += [(a, seed) for a in arms if seed in a.seeds]
    return order


def write_arms(output: Path, plan: Plan) -> None:
    """<output>/arms.csv: what each arm is (and, for matched arms, each seed's rate in match.yaml)."""
    with (output / 'arms.csv').open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(('arm', 'label', 'group', 'mode', 'seeds', 'learner', 'expert', 'match'))
        for arm in plan.arms:
            writer.writerow(
                (
                    arm.name,
                    arm.label,
                    arm.group,
                    arm.mode,
                    ' '.join(map(str, arm.seeds)),
                    yaml.safe_dump(arm.learner, default_flow_style=True).strip() if arm.learner else '',
                    yaml.safe_dump(arm.expert, default_flow_style=True).strip() if arm.expert else '',
                    arm.match,
                )
            )


def gather(output: Path, plan: Plan) -> None:
    arms = [a.name for a in plan.arms]
    seeds = sorted({s for a in plan.arms for s in a.seeds})
    gathering.gather(output, arms, seeds, label='arm')
    rows = []
    for arm in plan.arms:
        for seed in arm.seeds:
            run = run_dir(output, arm.name, seed)
            if (run / 'DONE').exists() and (run / 'gates.csv').exists():
                with (run / 'gates.csv').open(newline='') as f:
                    rows += [[arm.name, seed, *r.values()] for r in csv.DictReader(f)]
    if rows:
        with (output / 'gates.csv').open('w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow(('arm', 'seed', *GATE_FIELDS))
            writer.writerows(rows)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        prog='eqhrl-study',
        description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    parser.add_argument('--plan', default='pendulum', help='study plan (name or path)')
    parser.add_argument('--output', required=True, help='output folder')
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1, help='parallel runs (one core each)')
    parser.add_argument('--groups', nargs='+', help='run only these groups (default: all, in order)')
    parser.add_argument('--max-seeds', type=int, help='run only the first N seeds of each group')
    parser.add_argument('--list', action='store_true', help='print the runs and what is finished; run nothing')
    experiment.add_cluster(parser)
    experiment.add_save_every(parser)
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        plan = load_plan(args.plan)
        settings = {arm.name: arm_settings(plan, arm, args.save_every) for arm in plan.arms}
    except (ValueError, FileNotFoundError, KeyError) as error:
        print(f'eqhrl-study: {error}', file=sys.stderr)
        return 2
    if args.groups:
        unknown = sorted(set(args.groups) - {a.group for a in plan.arms})
        if unknown:
            print(f'eqhrl-study: no group(s) {unknown} in {plan.path}', file=sys.stderr)
            return 2
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / 'plan.yaml').write_text(Path(plan.path).read_text())
    write_arms(output, plan)

    runs = run_list(plan)
    if args.groups:
        runs = [(a, s) for a, s in runs if a.group in args.groups]
    if args.max_seeds:
        runs = [(a, s) for a, s in runs if a.seeds.index(s) < args.max_seeds]
    done = [(a, s) for a, s in runs if (run_dir(output, a.name, s) / 'DONE').exists()]
    todo = [(a, s) for a, s in runs if (a, s) not in done]
    steps = len(todo) * plan.episodes * (plan.max_steps or settings[plan.arms[0].name].max_episode_steps)
    durations = [d for d in (run_minutes(run_dir(output, a.name, s)) for a, s in done) if d is not None]
    if not todo:
        estimate = ''
    elif durations:
        per_run = sum(durations) / len(durations)
        left = per_run * len(todo) / max(1, min(args.jobs, len(todo)))
        estimate = f'; about {left:.0f} min ({per_run:.1f} min a run so far)'
    else:
        estimate = '; no time estimate yet (no finished run here says how long it took)'
    print(
        f'study {plan.name} ({plan.path}): {len(runs)} runs, {len(done)} finished, {len(todo)} to do '
        f'(at most {steps:,} env steps), {args.jobs} in parallel{estimate}',
        flush=True,
    )
    if args.list:
        for arm, seed in runs:
            mark = 'done' if (arm, seed) in done else 'todo'
            print(f'  {mark}  {arm.group:12s} {arm.name:24s} seed {seed}')
        return 0

    progress = progress_queue(args.cluster)
    start, finished, pending, running = time.monotonic(), 0, list(todo), {}
    try:
        with experiment.stopping_like_ctrl_c(), run_pool(max(1, min(args.jobs, len(todo) or 1)), args.cluster) as pool:
            if args.cluster:
                print(f'on the Dask cluster at {args.cluster}: {pool.slots} worker threads', flush=True)
            while pending or running:
                for key, result in list(running.items()):
                    if result.ready():
                        result.get()  # a worker's error ends the study here; finished runs are kept
                        del running[key]
                        finished += 1
                        arm, seed = key
                        elapsed = (time.monotonic() - start) / 60
                        left = elapsed / finished * (len(todo) - finished)  # at this process's pace so far
                        print(
                            f'[{finished}/{len(todo)} runs, {elapsed:.1f} min, about {left:.0f} min left] '
                            f'{arm} seed {seed} done',
                            flush=True,
                        )
                        gather(output, plan)  # a study read half-way (or killed) has its runs gathered
                for arm, seed in list(pending):
                    if len(running) >= (pool.slots if args.cluster else args.jobs):
                        break
                    ready = _ready(plan, arm, seed, output, settings)
                    if ready is None:
                        continue  # its matched run is not finished yet
                    pending.remove((arm, seed))
                    started = run_dir(output, arm.name, seed)
                    started.mkdir(parents=True, exist_ok=True)
                    (started / 'STARTED').touch()
                    running[(arm.name, seed)] = pool.apply_async(
                        run_worker,
                        (ready, arm.mode, seed, run_dir(output, arm.name, seed), False, progress, 0),
                    )
                while True:  # progress is only for the Manager's sake here: drain it
                    try:
                        progress.get_nowait()
                    except queue.Empty:
                        break
                if pending and not running:
                    stuck = ', '.join(
                        f'{a.name} seed {s} (matches {" and ".join(filter(None, (a.match, a.thins)))})'
                        for a, s in pending
                    )
                    print(f'eqhrl-study: waiting on runs outside this selection: {stuck}', file=sys.stderr)
                    return 2
                time.sleep(0.5)
    except KeyboardInterrupt:
        print('\ninterrupted: finished runs are kept; run the same command to continue', file=sys.stderr)
        gather(output, plan)
        return 130
    except ClusterUnavailable as error:
        print(f'eqhrl-study: {error}', file=sys.stderr)
        return 2
    gather(output, plan)
    print(f'{finished} runs finished in {(time.monotonic() - start) / 60:.1f} min; gathered in {output}')
    return 0


def _ready(plan: Plan, arm: Arm, seed: int, output: Path, settings: dict):
    """The settings to run (arm, seed) with, or None while the run it matches is unfinished."""
    own = settings[arm.name]
    if not arm.match:
        return own
    matched = run_dir(output, arm.match, seed)
    thinned = run_dir(output, arm.thins, seed) if arm.thins else None
    if not (matched / 'DONE').exists() or (thinned and not (thinned / 'DONE').exists()):
        return None
    rate, asked, steps = matched_rate(matched, budget_of(settings[arm.match]))
    record = {'matches': arm.match, 'requests': asked, 'steps': steps}
    if arm.thins:  # ask_random: the matched arm's requests over the thinned one's
        _, thin_asked, _ = matched_rate(thinned, budget_of(settings[arm.thins]))
        rate = min(1.0, asked / thin_asked) if thin_asked else 0.0
        learner = {'random_ask_rate': rate}
        record.update(thins=arm.thins, thinned_requests=thin_asked, random_ask_rate=rate)
    elif arm.match_timing == 'episode':
        schedule = [a for a, _ in requests_per_episode(matched, budget_of(settings[arm.match]))]
        learner = {'random_ask_schedule': schedule, 'random_ask_horizon': own.max_episode_steps}
        record.update(random_ask_schedule=schedule, random_ask_horizon=own.max_episode_steps)
    else:
        learner = {'random_ask_rate': rate}
        record.update(random_ask_rate=rate)
    run = run_dir(output, arm.name, seed)
    run.mkdir(parents=True, exist_ok=True)
    (run / 'match.yaml').write_text(yaml.safe_dump(record, default_flow_style=None))
    return dataclasses.replace(own, learner={**own.learner, **learner})


if __name__ == '__main__':
    sys.exit(main())
