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
  in number and in timing. With ``match_timing: steps`` (an extension; the named arm needs
  ``gate_trace``), each episode asks at the steps the named arm asked at in that episode of seed k,
  moved round the episode by a random offset (random_ask_steps): matched in number, gaps and runs
  of requests; where this arm's episode ends before a request's step, the next episode asks it
  (owed, so that the run's count holds on an env whose episodes end at different steps); the
  report's placement table checks it.
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
import os
import sys
from pathlib import Path

from ..experiments.seed_runs import run_dir
from ..experiments.study_plan import arm_settings, load_plan, run_list
from ..experiments.study_runs import run_study, time_left, write_arms
from . import experiment
from .arguments import at_least


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        prog='eqhrl-study',
        description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    parser.add_argument('--plan', default='pendulum', help='study plan (name or path)')
    parser.add_argument('--output', required=True, help='output folder')
    parser.add_argument('--jobs', type=at_least(1), default=os.cpu_count() or 1, help='parallel runs (one core each)')
    parser.add_argument('--groups', nargs='+', help='run only these groups (default: all, in order)')
    parser.add_argument('--max-seeds', type=at_least(1), help='run only the first N seeds of each group')
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
    estimate = time_left(output, plan, done, todo, args.jobs)
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

    status, _ = run_study(plan, settings, output, todo, args.jobs, args.cluster)
    return status


if __name__ == '__main__':
    sys.exit(main())
