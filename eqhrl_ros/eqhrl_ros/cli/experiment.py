"""eqhrl-experiment: SAC, QASAC and EQSAC over several seeds on one env, in parallel processes.

    eqhrl-experiment --params pendulum --seeds 0 1 2 3 4 --output runs/pendulum_paper
    eqhrl-experiment --params lunar_lander --seeds 0 1 --episodes 200 --output runs/lunar
    eqhrl-experiment --params demo --algorithms sac eqsac --seeds 0 1 --through-ros --output runs/ros

Defaults (env, hyperparameters, episodes, steps per episode, budget, expert) come
from the params file; options override them. Each run writes
<output>/<algorithm>/seed<k>/episodes.csv (the learner node's format) and a DONE
marker when finished; <output>/episodes.csv gathers all finished runs with the
columns of COLUMNS. In-process runs also evaluate the policy without advice every
--eval-every episodes from --eval-starts fixed start states (core/runs/evaluation.py):
<run>/eval.csv, gathered into <output>/eval.csv (EVAL_COLUMNS). Interrupt with Ctrl-C and run the same command again:
finished runs are skipped; an unfinished lone in-process run continues from its last save
(every --save-every minutes, between episodes: core/runs/resume_point.py) and writes what it
would have written uninterrupted; runs through ROS and seeds learning together start over.

Seeds of an algorithm learn together in one process where that is faster (small networks,
see --seeds-together; core/algorithm/stacked_seeds.py): the same numbers as learning apart, to float
rounding. --seeds-apart runs every seed in a process of its own, as --through-ros does.

--through-ros runs each seed through the three ROS nodes (eqhrl-train) instead of
the in-process core: same algorithm, same CSV, numbers equal up to scheduling.
--env-node COMMAND (with --through-ros) starts your own env node for each run instead of
gym_env, in the run's private ROS domain:

    eqhrl-experiment --params double_integrator --through-ros --output runs/di \
        --env-node "double_integrator_env --ros-args -p seed:={seed}"
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ..core.algorithm.config import MODES as ALGORITHMS
from ..core.algorithm.config import PAPER_MODES
from ..core.experts.factory import EXPERT_BACKENDS
from ..experiments.experiment_runs import submit_runs, wait_for_runs, write_settings
from ..experiments.gather import gather
from ..experiments.progress import EpisodeCount
from ..experiments.run_pool import ClusterUnavailable, RunFailed, progress_queue, run_pool, stopping_like_ctrl_c
from ..experiments.seed_runs import (
    run_dir,
    seeds_together_by_default,
    seeds_together_refusal,
)
from ..experiments.settings import Settings, load_settings
from .arguments import at_least, config_value


def add_save_every(parser) -> None:
    """--save-every, the same for eqhrl-experiment and eqhrl-study."""
    parser.add_argument(
        '--save-every',
        type=float,
        metavar='MINUTES',
        help='a lone in-process run saves its state between episodes this often, and an interrupted one '
        f'continues from there when the command runs again (default {Settings.save_every_s / 60:g}; 0: never)',
    )


def add_cluster(parser) -> None:
    parser.add_argument(
        '--cluster',
        default='',
        metavar='ADDRESS',
        help='hand the runs to the Dask scheduler at ADDRESS (e.g. tcp://10.0.0.5:8786) instead of --jobs local '
        'processes; every worker needs this package and the output folder at the same path (README)',
    )


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        prog='eqhrl-experiment',
        description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    parser.add_argument('--params', default='pendulum', help='params file (name or path) with the defaults')
    parser.add_argument('--env', help='gymnasium env id (default: from the params file)')
    parser.add_argument(
        '--algorithms',
        nargs='+',
        choices=ALGORITHMS,
        default=list(PAPER_MODES),
        help="modes to run (default: the paper's three; respond and random are ablations, see eqhrl-study)",
    )
    parser.add_argument('--seeds', nargs='+', type=config_value('seed'), default=[0, 1, 2, 3, 4])
    parser.add_argument('--episodes', type=at_least(1), help='episodes per run (default: max_episodes of the file)')
    parser.add_argument('--max-steps', type=at_least(1), help='steps per episode (default: from the file)')
    parser.add_argument('--budget', type=config_value('advising_budget'), help='early-advising budget in episodes')
    parser.add_argument('--expert', choices=(*EXPERT_BACKENDS, 'none'), help='expert backend')
    parser.add_argument('--policy-path', help='policy file for --expert policy')
    parser.add_argument('--output', required=True, help='output folder')
    parser.add_argument('--jobs', type=at_least(1), default=os.cpu_count() or 1, help='parallel runs')
    parser.add_argument('--through-ros', action='store_true', help='run through the ROS nodes')
    parser.add_argument(
        '--eval-every',
        type=int,
        default=10,
        help='every N episodes (and after the last), the deterministic policy alone, without advice, from '
        'fixed start states; written to eval.csv (in-process runs; 0: none)',
    )
    parser.add_argument('--eval-starts', type=int, default=10, help='start states of each evaluation')
    parser.add_argument(
        '--record',
        action='store_true',
        help="each run's record.mcap (the learner's record: true; in-process runs write their advised "
        'transitions and episodes)',
    )
    parser.add_argument(
        '--prior',
        nargs='+',
        metavar='RUN_OR_MCAP',
        help='earlier runs (folders, searched below, or .mcap files) whose advised and person-initiated '
        "transitions go into each run's D and D_advising before its first step (the learner's prior)",
    )
    add_cluster(parser)
    add_save_every(parser)
    batching = parser.add_mutually_exclusive_group()
    batching.add_argument(
        '--seeds-apart',
        action='store_true',
        help='one process per run, seeds one after the other (default for networks where learning '
        'together is not faster: see --seeds-together)',
    )
    batching.add_argument(
        '--seeds-together',
        action='store_true',
        help="the seeds of an algorithm split over --jobs processes, each process's seeds learning together "
        '(one batched matrix product per layer for all of them; the same numbers as apart to float rounding). '
        'Default where measured faster: hidden width squared x batch size <= 64 x 64 x 256 (in-process runs)',
    )
    parser.add_argument(
        '--env-node',
        metavar='COMMAND',
        help='with --through-ros: start this command as the env node of each run instead of gym_env, '
        'e.g. "ros2 run my_pkg my_env --ros-args -p seed:={seed}" ({seed} and {max_steps} are filled in); '
        'the learner and expert take the spaces from its env_info',
    )
    args = parser.parse_args(argv)
    for name in ('seeds', 'algorithms'):  # each pair is one run folder: twice, its rows were gathered twice
        given = getattr(args, name)
        twice = sorted({str(value) for value in given if given.count(value) > 1})
        if twice:
            parser.error(f'argument --{name}: {", ".join(twice)} given more than once (each is one run)')
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        settings = load_settings(args)
        refusal = seeds_together_refusal(settings, args.through_ros) if args.seeds_together else ''
        if refusal:
            raise ValueError(refusal)
    except (ValueError, FileNotFoundError) as error:
        print(f'eqhrl-experiment: {error}', file=sys.stderr)
        return 2
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    write_settings(output, settings, args)

    todo = [(a, s) for a in args.algorithms for s in args.seeds if not (run_dir(output, a, s) / 'DONE').exists()]
    skipped = len(args.algorithms) * len(args.seeds) - len(todo)
    together = not args.through_ros and (
        args.seeds_together or (not args.seeds_apart and seeds_together_by_default(settings))
    )
    jobs = max(1, min(args.jobs, len(todo) or 1))
    env = settings.env_id or settings.env_node or settings.file_env_node
    print(
        f'{env}: {len(todo)} runs to do ({skipped} finished already), '
        f'{settings.episodes} episodes x {settings.max_episode_steps} steps, {args.jobs} in parallel, '
        f'{"through ROS" if args.through_ros else "in-process"}'
        f'{", seeds together" if together else ""}',
        flush=True,
    )
    count, start = EpisodeCount(len(todo) * settings.episodes), time.monotonic()
    try:
        with stopping_like_ctrl_c(), progress_queue(args.cluster) as progress, run_pool(jobs, args.cluster) as pool:
            tasks = submit_runs(
                pool, settings, args.algorithms, todo, output, progress, together, jobs, args.through_ros
            )
            wait_for_runs(tasks, todo, output, count, progress, args.cluster, start)
    except KeyboardInterrupt:
        print('\ninterrupted: finished runs are kept; run the same command to continue', file=sys.stderr)
        gather(output, args.algorithms, args.seeds)
        return 130
    except ClusterUnavailable as error:
        print(f'eqhrl-experiment: {error}', file=sys.stderr)
        return 2
    except RunFailed as error:
        print(f'eqhrl-experiment: {error}; finished runs are kept: run the same command to continue', file=sys.stderr)
        gather(output, args.algorithms, args.seeds)
        return 1
    path = gather(output, args.algorithms, args.seeds)
    print(f'all runs finished in {(time.monotonic() - start) / 60:.1f} min; episodes in {path}')
    return 0
