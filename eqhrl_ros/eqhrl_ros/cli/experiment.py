"""eqhrl-experiment: SAC, QASAC and EQSAC over several seeds on one env, in parallel processes.

    eqhrl-experiment --params pendulum --seeds 0 1 2 3 4 --output runs/pendulum_paper
    eqhrl-experiment --params lunar_lander --seeds 0 1 --episodes 200 --output runs/lunar
    eqhrl-experiment --params demo --algorithms sac eqsac --seeds 0 1 --through-ros --output runs/ros

Defaults (env, hyperparameters, episodes, steps per episode, budget, expert) come
from the params file; options override them. Each run writes
<output>/<algorithm>/seed<k>/episodes.csv (the learner node's format) and a DONE
marker when finished; <output>/episodes.csv gathers all finished runs with the
columns of COLUMNS. Interrupt with Ctrl-C and run the same command again:
finished runs are skipped, unfinished ones start over.

--through-ros runs each seed through the three ROS nodes (eqhrl-train) instead of
the in-process core: same algorithm, same CSV, numbers equal up to scheduling.
"""

from __future__ import annotations

import argparse
import csv
import multiprocessing as mp
import os
import queue
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from ..core.config import MODES as ALGORITHMS
from ..core.experts import EXPERT_BACKENDS
from ..paths import params_file

COLUMNS = ('algorithm', 'seed', 'episode', 'return', 'length', 'advice_asked', 'advice_given', 'success')


@dataclass
class Settings:
    env_id: str
    learner: dict  # learner node parameters from the params file
    max_episode_steps: int
    episodes: int
    expert_backend: str = 'heuristic'
    policy_path: str = ''
    params_path: str = ''


def load_settings(args) -> Settings:
    """The params file's sections, refused as the nodes would refuse them (a typo included)."""
    from ..nodes.params import EXPERT_PARAMS, GYM_ENV_PARAMS, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS, check_section

    path = params_file(args.params)
    data = yaml.safe_load(path.read_text())
    learner = dict(data.get('learner', {}).get('ros__parameters', {}))
    env = data.get('gym_env', {}).get('ros__parameters', {})
    expert = data.get('expert', {}).get('ros__parameters', {})
    check_section('learner', learner, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)
    check_section('gym_env', env, GYM_ENV_PARAMS)
    check_section('expert', expert, EXPERT_PARAMS)
    if args.budget is not None:
        learner['advising_budget'] = args.budget
    settings = Settings(
        env_id=args.env or learner.get('env_id') or env.get('env_id', 'Pendulum-v1'),
        learner=learner,
        max_episode_steps=args.max_steps or int(env.get('max_episode_steps', 100)),
        episodes=args.episodes or int(learner.get('max_episodes', 0)) or 200,
        expert_backend=args.expert or expert.get('backend', 'heuristic'),
        policy_path=args.policy_path or expert.get('policy_path', ''),
        params_path=str(path),
    )
    return settings


def learner_config(settings: Settings, algorithm: str, seed: int):
    from ..core import LearnerConfig
    from ..nodes.params import LEARNER_NODE_PARAMS

    return LearnerConfig.from_params(
        settings.learner, node_keys=[p.name for p in LEARNER_NODE_PARAMS], mode=algorithm, seed=seed
    )


def make_expert(settings: Settings):
    from ..core.experts import make_expert as expert_for

    if settings.expert_backend == 'none':
        return None
    return expert_for(settings.expert_backend, settings.env_id, settings.policy_path)


def run_dir(output: Path, algorithm: str, seed: int) -> Path:
    return output / algorithm / f'seed{seed}'


def run_in_process(settings: Settings, algorithm: str, seed: int, directory: Path, progress) -> None:
    import torch

    from ..core import EpisodeSummary, EQSACLearner, make_env, success_criterion, train
    from ..core.records import EpisodeRecord

    torch.set_num_threads(1)  # one process per core
    env = make_env(settings.env_id, settings.max_episode_steps)
    learner = EQSACLearner(
        int(env.observation_space.shape[0]),
        env.action_space.low,
        env.action_space.high,
        learner_config(settings, algorithm, seed),
        success_criterion(settings.env_id),
    )
    record = EpisodeRecord(directory / 'episodes.csv', EpisodeSummary.CSV_FIELDS)  # the learner node's record

    def on_episode(summary):
        error = record.append(summary.csv_row())
        if error is not None:
            raise error  # the run fails; running the command again redoes it
        progress.put((algorithm, seed, summary.episode, summary.episode_return))

    try:
        train(env, learner, settings.episodes, make_expert(settings), seed=seed, on_episode=on_episode)
    finally:
        record.close()
        env.close()


def run_through_ros(settings: Settings, algorithm: str, seed: int, directory: Path, progress) -> None:
    command = [
        str(Path(sys.prefix) / 'bin' / 'eqhrl-train'),
        '--params',
        settings.params_path,
        '--output',
        str(directory),
        '--mode',
        algorithm,
        '--episodes',
        str(settings.episodes),
        '--seed',
        str(seed),
        '--max-steps',
        str(settings.max_episode_steps),
        '--overwrite',
    ]  # an unfinished run starts over
    if 'advising_budget' in settings.learner:
        command += ['--budget', str(settings.learner['advising_budget'])]
    if settings.expert_backend == 'none':
        command += ['--expert-node', 'none']
    env = dict(os.environ, OMP_NUM_THREADS='1')
    # A private domain per run, so that parallel runs never exchange messages.
    env['ROS_DOMAIN_ID'] = str(1 + (os.getpid() + seed * 7 + ALGORITHMS.index(algorithm)) % 100)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    with (directory / 'train.log').open('w') as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
        seen = 0
        while process.poll() is None:
            time.sleep(1.0)
            seen = _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
        _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
    if process.returncode != 0:
        raise RuntimeError(f'eqhrl-train failed for {algorithm} seed {seed}; see {directory / "train.log"}')


def _report_new_rows(path: Path, seen: int, algorithm: str, seed: int, progress) -> int:
    if not path.exists():
        return seen
    with path.open(newline='') as f:
        rows = list(csv.DictReader(f))
    for row in rows[seen:]:
        progress.put((algorithm, seed, int(row['episode']), float(row['return'])))
    return len(rows)


def _worker(settings, algorithm, seed, directory, through_ros, progress) -> tuple:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / 'DONE').unlink(missing_ok=True)
    start = time.monotonic()
    (run_through_ros if through_ros else run_in_process)(settings, algorithm, seed, directory, progress)
    elapsed = time.monotonic() - start
    (directory / 'DONE').write_text(f'{elapsed:.1f}\n')
    return algorithm, seed, elapsed


def gather(output: Path, algorithms, seeds) -> Path:
    """Write <output>/episodes.csv from every finished run."""
    path = output / 'episodes.csv'
    with path.open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for algorithm in algorithms:
            for seed in seeds:
                directory = run_dir(output, algorithm, seed)
                if not (directory / 'DONE').exists():
                    continue
                with (directory / 'episodes.csv').open(newline='') as run_csv:
                    for row in csv.DictReader(run_csv):
                        writer.writerow(
                            [
                                algorithm,
                                seed,
                                row['episode'],
                                row['return'],
                                row['length'],
                                row['advice_asked'],
                                row['advice_given'],
                                row['success'],
                            ]
                        )
    return path


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        prog='eqhrl-experiment',
        description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    parser.add_argument('--params', default='pendulum', help='params file (name or path) with the defaults')
    parser.add_argument('--env', help='gymnasium env id (default: from the params file)')
    parser.add_argument('--algorithms', nargs='+', choices=ALGORITHMS, default=list(ALGORITHMS))
    parser.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument('--episodes', type=int, help='episodes per run (default: max_episodes of the file)')
    parser.add_argument('--max-steps', type=int, help='steps per episode (default: from the file)')
    parser.add_argument('--budget', type=int, help='early-advising budget in episodes')
    parser.add_argument('--expert', choices=(*EXPERT_BACKENDS, 'none'), help='expert backend')
    parser.add_argument('--policy-path', help='policy file for --expert policy')
    parser.add_argument('--output', required=True, help='output folder')
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1, help='parallel runs')
    parser.add_argument('--through-ros', action='store_true', help='run through the ROS nodes')
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        settings = load_settings(args)
    except (ValueError, FileNotFoundError) as error:
        print(f'eqhrl-experiment: {error}', file=sys.stderr)
        return 2
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / 'settings.yaml').write_text(
        yaml.safe_dump(
            {
                'env_id': settings.env_id,
                'episodes': settings.episodes,
                'max_episode_steps': settings.max_episode_steps,
                'algorithms': args.algorithms,
                'seeds': args.seeds,
                'expert': settings.expert_backend,
                'through_ros': args.through_ros,
                'params_file': settings.params_path,
                'learner': settings.learner,
            }
        )
    )

    todo = [(a, s) for a in args.algorithms for s in args.seeds if not (run_dir(output, a, s) / 'DONE').exists()]
    skipped = len(args.algorithms) * len(args.seeds) - len(todo)
    print(
        f'{settings.env_id}: {len(todo)} runs to do ({skipped} finished already), '
        f'{settings.episodes} episodes x {settings.max_episode_steps} steps, {args.jobs} in parallel, '
        f'{"through ROS" if args.through_ros else "in-process"}',
        flush=True,
    )
    total = len(todo) * settings.episodes
    done_episodes, finished, start = 0, 0, time.monotonic()
    last_print = 0.0
    manager = mp.Manager()
    progress = manager.Queue()
    context = mp.get_context('spawn')
    try:
        with context.Pool(max(1, min(args.jobs, len(todo) or 1))) as pool:
            results = [
                pool.apply_async(_worker, (settings, a, s, run_dir(output, a, s), args.through_ros, progress))
                for a, s in todo
            ]
            while finished < len(results):
                try:
                    algorithm, seed, episode, ret = progress.get(timeout=0.5)
                    done_episodes += 1
                except queue.Empty:
                    pass
                newly = sum(r.ready() for r in results) - finished
                for r in results:
                    if r.ready() and not r.successful():
                        r.get()  # re-raise a worker's error here
                finished += newly
                now = time.monotonic()
                if now - last_print > 15.0 or newly:
                    last_print = now
                    rate = done_episodes / max(now - start, 1e-9)
                    eta = (total - done_episodes) / rate if rate > 0 else float('nan')
                    print(
                        f'[{done_episodes}/{total} episodes, {finished}/{len(results)} runs] '
                        f'{100 * done_episodes / max(total, 1):5.1f}%  eta {eta / 60:5.1f} min',
                        flush=True,
                    )
    except KeyboardInterrupt:
        print('\ninterrupted: finished runs are kept; run the same command to continue', file=sys.stderr)
        gather(output, args.algorithms, args.seeds)
        return 130
    path = gather(output, args.algorithms, args.seeds)
    print(f'all runs finished in {(time.monotonic() - start) / 60:.1f} min; episodes in {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
