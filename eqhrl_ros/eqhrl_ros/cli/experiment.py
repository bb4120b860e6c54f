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
import contextlib
import csv
import dataclasses
import math
import numbers
import os
import queue
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..core.algorithm.config import MODES as ALGORITHMS
from ..core.algorithm.config import PAPER_MODES
from ..core.experts.factory import EXPERT_BACKENDS
from ..paths import params_file
from ..yaml_files import load_mapping
from .run_pool import ClusterUnavailable, progress_queue, run_pool

DEFAULT_EPISODES = 200  # --episodes where neither it nor the params file's max_episodes is set
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
    env_node: str = ''  # a command that starts the user's env node (--env-node), or ''
    eval_every: int = 0  # advice-free evaluation every N episodes (in-process runs; 0: none)
    eval_starts: int = 10  # fixed start states of each evaluation
    # An imperfect expert (in-process runs; eqhrl-study): 'human' (simulated_human.HumanLimits
    # fields, the expert backend then simulated_human), 'delay_steps', 'gain' (imperfect_experts).
    expert_options: dict = field(default_factory=dict)
    gate_trace: bool = False  # write <run>/gates.csv: D(s), E(s) and thresholds inside the budget
    # A lone in-process run saves its state between episodes this often (seconds; 0: never),
    # and an interrupted one continues from there (core/runs/resume_point.py). --save-every.
    save_every_s: float = 300.0


def load_settings(args) -> Settings:
    """The params file's sections, refused as the nodes would refuse them (a typo included)."""
    from ..parameters import (
        EXPERT_PARAMS,
        GYM_ENV_PARAMS,
        LEARNER_CONFIG_PARAMS,
        LEARNER_NODE_PARAMS,
        check_section,
        default_of,
        file_section,
    )

    path = params_file(args.params)
    data = load_mapping(path, 'params file')
    learner = file_section(data, 'learner')
    env = file_section(data, 'gym_env')
    expert = file_section(data, 'expert')
    check_section('learner', learner, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)
    check_section('gym_env', env, GYM_ENV_PARAMS)
    check_section('expert', expert, EXPERT_PARAMS)
    if args.budget is not None:
        learner['advising_budget'] = args.budget
    save_every = getattr(args, 'save_every', None)
    if save_every is not None and not (save_every >= 0 and math.isfinite(save_every)):
        raise ValueError(f'--save-every must be >= 0 minutes (0: never), got {save_every}')
    if args.eval_every < 0 or args.eval_starts < 1:
        raise ValueError(
            f'--eval-every must be >= 0 and --eval-starts >= 1 (got {args.eval_every}, {args.eval_starts})'
        )
    if args.env_node:
        if not args.through_ros:
            raise ValueError('--env-node runs an env node, so it needs --through-ros')
        env_node_command(args.env_node, 0, 1)  # refuses an empty command or a program not found
    settings = Settings(
        env_id=args.env
        or learner.get('env_id')
        or env.get('env_id')
        or ('' if args.env_node else default_of(GYM_ENV_PARAMS, 'env_id')),
        learner=learner,
        max_episode_steps=args.max_steps
        or int(env.get('max_episode_steps', default_of(GYM_ENV_PARAMS, 'max_episode_steps'))),
        # A learner node's max_episodes of 0 means "never stop"; a run of experiments needs an end.
        episodes=args.episodes or int(learner.get('max_episodes', 0)) or DEFAULT_EPISODES,
        expert_backend=args.expert or expert.get('backend', default_of(EXPERT_PARAMS, 'backend')),
        policy_path=args.policy_path or expert.get('policy_path', default_of(EXPERT_PARAMS, 'policy_path')),
        params_path=str(path),
        env_node=args.env_node or '',
        eval_every=0 if args.through_ros else args.eval_every,
        eval_starts=args.eval_starts,
    )
    if save_every is not None:
        settings.save_every_s = 60.0 * save_every
    return settings


def learner_config(settings: Settings, algorithm: str, seed: int):
    from ..core import LearnerConfig
    from ..parameters import LEARNER_NODE_PARAMS

    return LearnerConfig.from_params(
        settings.learner, node_keys=[p.name for p in LEARNER_NODE_PARAMS], mode=algorithm, seed=seed
    )


def make_expert(settings: Settings, seed: int = 0):
    """The run's expert: the backend of the settings, made imperfect by expert_options."""
    from ..core.experts.factory import make_expert as expert_for
    from ..core.experts.imperfect import DelayedExpert, WeakExpert
    from ..core.experts.simulated_human import HumanLimits

    if settings.expert_backend == 'none':
        return None
    options = dict(settings.expert_options)
    unknown = sorted(set(options) - {'human', 'delay_steps', 'gain'})
    if unknown:
        raise ValueError(f'unknown expert option(s) {unknown}; known: human, delay_steps, gain')
    backend = 'simulated_human' if 'human' in options else settings.expert_backend
    limits = HumanLimits(**options['human']) if 'human' in options else None
    # The person's own random stream: one per seed, apart from the learner's.
    expert = expert_for(backend, settings.env_id, settings.policy_path, limits, seed=10_000 + seed)
    if options.get('gain', 1.0) != 1.0:
        expert = WeakExpert(expert, options['gain'])
    if options.get('delay_steps', 0):
        expert = DelayedExpert(expert, options['delay_steps'])
    return expert


def run_dir(output: Path, algorithm: str, seed: int) -> Path:
    return output / algorithm / f'seed{seed}'


def _seed_run(settings: Settings, algorithm: str, seed: int, directory: Path, progress, resume=None):
    """One seed's env, learner, expert and record files as a training.SeedRun, and a function
    that closes them. ``resume``: a core.runs.resume_point.ResumePoint to continue from if it
    holds a usable save (the records then keep their rows up to it), or None."""
    from ..core import EpisodeSummary, EQSACLearner, make_env, success_criterion
    from ..core.runs.evaluation import EVAL_FIELDS, eval_seeds
    from ..core.runs.in_process import Evaluation, SeedRun
    from ..core.runs.records import EpisodeRecord

    env = make_env(settings.env_id, settings.max_episode_steps)
    learner = EQSACLearner(
        int(env.observation_space.shape[0]),
        env.action_space.low,
        env.action_space.high,
        learner_config(settings, algorithm, seed),
        success_criterion(settings.env_id),
    )
    expert = make_expert(settings, seed)
    resumed = resume is not None and resume.restore(learner, env, expert)
    # Resumed after episode E: episodes 0..E-1, evaluations after up to E episodes, and the
    # gates of episodes 0..E-1 are kept; later rows are made again.
    keep = learner.episode if resumed else None
    record = EpisodeRecord(directory / 'episodes.csv', EpisodeSummary.CSV_FIELDS, keep)  # the learner node's record
    evaluation, eval_record = None, None
    if settings.eval_every:
        eval_record = EpisodeRecord(directory / 'eval.csv', EVAL_FIELDS, None if keep is None else keep + 1)

        def on_eval(results):
            for result in results:
                error = eval_record.append(result.csv_row())
                if error is not None:
                    raise error

        evaluation = Evaluation(
            make_env(settings.env_id, settings.max_episode_steps),
            settings.eval_every,
            eval_seeds(settings.eval_starts),
            on_eval,
        )

    def on_episode(summary):
        error = record.append(summary.csv_row())
        if error is not None:
            raise error  # the run fails; running the command again redoes it
        progress.put((algorithm, seed, summary.episode, summary.episode_return))

    gate_record, on_proposal = None, None
    if settings.gate_trace:
        gate_record = EpisodeRecord(directory / 'gates.csv', GATE_FIELDS, keep)

        def on_proposal(learner, proposal):
            decision = proposal.decision
            if decision.within_budget:
                error = gate_record.append([learner.episode, learner.episode_step, *gate_row(decision)])
                if error is not None:
                    raise error

    def close():
        record.close()
        env.close()
        if gate_record is not None:
            gate_record.close()
        if evaluation is not None:
            eval_record.close()
            evaluation.env.close()

    # A resumed run's env stream goes on from the save; a fresh one starts from the seed.
    run = SeedRun(env, learner, expert, None if resumed else seed, on_episode, evaluation, on_proposal)
    return run, close


def run_in_process(settings: Settings, algorithm: str, seed: int, directory: Path, progress, domain_id=None) -> float:
    """One run in this process, continued from its resume point if it has one (saved every
    settings.save_every_s between episodes: core/runs/resume_point.py). Returns the wall time of
    the run so far in seconds, earlier processes included."""
    import torch

    from ..core import train
    from ..core.runs.resume_point import ResumePoint

    torch.set_num_threads(1)  # one process per core
    identity = {'settings': dataclasses.asdict(settings), 'algorithm': algorithm, 'seed': seed}
    point = ResumePoint(directory, identity, settings.save_every_s, log=lambda line: print(line, flush=True))
    run, close = _seed_run(settings, algorithm, seed, directory, progress, resume=point)
    try:
        train(
            run.env,
            run.learner,
            settings.episodes,
            run.expert,
            seed=run.seed,
            on_episode=run.on_episode,
            evaluation=run.evaluation,
            on_proposal=run.on_proposal,
            between_episodes=lambda: point.save_if_due(run.learner, run.env, run.expert),
        )
    finally:
        close()
    return point.seconds


def run_together(settings: Settings, algorithm: str, seeds, output: Path, progress) -> None:
    """Several seeds of one algorithm in this process, their updates as one (core/algorithm/stacked_seeds.py):
    each seed's files and numbers as run_in_process would write them (to float rounding).
    A seed's DONE is written as soon as it finishes."""
    import torch

    from ..core.runs.in_process import train_together

    torch.set_num_threads(1)  # one process per core
    start = time.monotonic()
    runs, closers = [], []
    try:
        for seed in seeds:
            run, close = _seed_run(settings, algorithm, seed, run_dir(output, algorithm, seed), progress)
            closers.append(close)
            directory = run_dir(output, algorithm, seed)
            run.on_finished = lambda d=directory: (d / 'DONE').write_text(f'{time.monotonic() - start:.1f}\n')
            runs.append(run)
        train_together(runs, settings.episodes)
    finally:
        for close in closers:
            close()


# Seeds learn together (run_together) by default where that is faster: measured with
# benchmarks/bench_seeds.py (docs/performance.md, "Many seeds in one process"), 10 seeds on
# 2 cores were 2.2x faster together with 64x64 networks and batch 128, and no faster with
# 128x128 and batch 256 or Table 1's 256x256 and 256, where the matrix products fill the cores.
TOGETHER_MAX_WORK = 64 * 64 * 256  # hidden width squared times batch size


def seeds_together_by_default(settings: Settings) -> bool:
    config = learner_config(settings, 'sac', 0)
    return config.advice_batch == 'full' and max(config.hidden) ** 2 * config.batch_size <= TOGETHER_MAX_WORK


def seeds_together_refusal(settings: Settings, through_ros: bool) -> str:
    """Why --seeds-together cannot be had with these settings, or ''."""
    if through_ros:
        return '--seeds-together runs in-process; --through-ros runs each seed in nodes of its own'
    if learner_config(settings, 'sac', 0).advice_batch != 'full':
        return "--seeds-together needs advice_batch 'full' (with 'proportional' each seed has a batch size of its own)"
    return ''


# gates.csv: where a decision was made, then these GateDecision fields (tests/test_one_home.py).
GATE_COLUMNS = ('discrepancy', 'd_threshold', 'entropy', 'e_threshold', 'ask', 'respond', 'fire')
GATE_FIELDS = ('episode', 'step', *GATE_COLUMNS)


def gate_row(decision) -> list:
    """A GateDecision as GATE_COLUMNS: numbers to 6 significant digits (NaN: not evaluated, or
    a queue still empty), flags as 0 or 1."""
    values = (getattr(decision, name) for name in GATE_COLUMNS)
    return [f'{v:.6g}' if isinstance(v, numbers.Real) and not isinstance(v, bool) else int(v) for v in values]


def run_through_ros(settings: Settings, algorithm: str, seed: int, directory: Path, progress, domain_id: int) -> None:
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
    if settings.env_node:
        command += ['--env-node', 'none', '--discovery', 'localhost']
    env = dict(os.environ, OMP_NUM_THREADS='1')
    # A private domain per run, so that parallel runs never exchange messages.
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env_node = None
    with (directory / 'train.log').open('w') as log:
        if settings.env_node:
            with (directory / 'env_node.log').open('w') as env_log:
                env_node = subprocess.Popen(
                    env_node_command(settings.env_node, seed, settings.max_episode_steps),
                    stdout=env_log,
                    stderr=subprocess.STDOUT,
                    env=env,
                )
        try:
            process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
            seen = 0
            while process.poll() is None:
                time.sleep(1.0)
                seen = _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
                if env_node is not None and env_node.poll() is not None:
                    process.send_signal(signal.SIGINT)  # the env is gone: stop and save
                    process.wait()
                    raise RuntimeError(
                        f'the env node exited ({env_node.returncode}) for {algorithm} seed {seed}; '
                        f'see {directory / "env_node.log"}'
                    )
            _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
        finally:
            if env_node is not None and env_node.poll() is None:
                env_node.send_signal(signal.SIGINT)
                try:
                    env_node.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    env_node.kill()
                    env_node.wait()
    if process.returncode != 0:
        raise RuntimeError(f'eqhrl-train failed for {algorithm} seed {seed}; see {directory / "train.log"}')


def env_node_command(template: str, seed: int, max_steps: int) -> list:
    """The user's env node command with {seed} and {max_steps} filled in. A program that is not
    on PATH but in this environment's bin (the package's own nodes, in a venv) is found there."""
    words = shlex.split(template.format(seed=seed, max_steps=max_steps))
    if not words:
        raise ValueError('--env-node is empty')
    found = shutil.which(words[0]) or shutil.which(words[0], path=str(Path(sys.prefix) / 'bin'))
    if found is None:
        raise ValueError(f'--env-node: {words[0]!r} is neither on PATH nor in {Path(sys.prefix) / "bin"}')
    return [found, *words[1:]]


def _report_new_rows(path: Path, seen: int, algorithm: str, seed: int, progress) -> int:
    if not path.exists():
        return seen
    with path.open(newline='') as f:
        rows = list(csv.DictReader(f))
    for row in rows[seen:]:
        progress.put((algorithm, seed, int(row['episode']), float(row['return'])))
    return len(rows)


class EpisodeCount:
    """The progress line of a command's runs: episodes done of ``total``, where a resumed run's
    earlier episodes count as done (its first report here is episode E, not 0), and the time
    left from the rate of the episodes run in this process only."""

    def __init__(self, total: int):
        self.total = total
        self.next_episode = {}  # (algorithm, seed) -> episodes the run has done
        self.run_here = 0

    def add(self, report) -> None:
        """One progress report: (algorithm, seed, episode, return)."""
        algorithm, seed, episode, _ = report
        self.next_episode[(algorithm, seed)] = max(self.next_episode.get((algorithm, seed), 0), int(episode) + 1)
        self.run_here += 1

    @property
    def done(self) -> int:
        return sum(self.next_episode.values())

    def line(self, runs_done: int, runs: int, seconds: float) -> str:
        rate = self.run_here / max(seconds, 1e-9)
        eta = (self.total - self.done) / rate if rate > 0 else float('nan')
        return (
            f'[{self.done}/{self.total} episodes, {runs_done}/{runs} runs] '
            f'{100 * self.done / max(self.total, 1):5.1f}%  eta {eta / 60:5.1f} min'
        )


def domain_ids(count: int) -> list:
    """A ROS domain per run, distinct among the runs of one experiment (at most 100 at a
    time), offset by this process's id so that two experiments on one machine rarely meet."""
    return [1 + (os.getpid() + index) % 100 for index in range(count)]


def run_worker(settings, algorithm, seed, directory, through_ros, progress, domain_id) -> tuple:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / 'DONE').unlink(missing_ok=True)
    start = time.monotonic()
    if through_ros:
        run_through_ros(settings, algorithm, seed, directory, progress, domain_id)
        elapsed = time.monotonic() - start
    else:
        elapsed = run_in_process(settings, algorithm, seed, directory, progress, domain_id)
    (directory / 'DONE').write_text(f'{elapsed:.1f}\n')
    if not through_ros:
        from ..core.runs.resume_point import remove_files

        remove_files(directory)  # after DONE: a run killed in between is not redone
    return algorithm, seed, elapsed


def _group_worker(settings, algorithm, seeds, output, progress) -> tuple:
    """Seeds of one algorithm together in this process (run_together)."""
    for seed in seeds:
        directory = run_dir(output, algorithm, seed)
        directory.mkdir(parents=True, exist_ok=True)
        (directory / 'DONE').unlink(missing_ok=True)
    start = time.monotonic()
    run_together(settings, algorithm, seeds, output, progress)
    return algorithm, tuple(seeds), time.monotonic() - start


def gather(output: Path, algorithms, seeds, label: str = 'algorithm') -> Path:
    """Write <output>/episodes.csv from every finished run (and <output>/eval.csv from their
    advice-free evaluations, where they have one). ``label``: the first column's name (a
    study's runs are arms, not algorithms)."""
    _gather_eval(output, algorithms, seeds, label)
    path = output / 'episodes.csv'
    with path.open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow((label, *COLUMNS[1:]))
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


EVAL_COLUMNS = ('algorithm', 'seed', 'episode', 'start', 'return', 'length', 'success')


def _gather_eval(output: Path, algorithms, seeds, label: str = 'algorithm') -> None:
    rows = []
    for algorithm in algorithms:
        for seed in seeds:
            directory = run_dir(output, algorithm, seed)
            if (directory / 'DONE').exists() and (directory / 'eval.csv').exists():
                with (directory / 'eval.csv').open(newline='') as run_csv:
                    rows += [[algorithm, seed, *(r[c] for c in EVAL_COLUMNS[2:])] for r in csv.DictReader(run_csv)]
    if rows:
        with (output / 'eval.csv').open('w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow((label, *EVAL_COLUMNS[1:]))
            writer.writerows(rows)


def add_save_every(parser) -> None:
    """--save-every, the same for eqhrl-experiment and eqhrl-study."""
    parser.add_argument(
        '--save-every',
        type=float,
        metavar='MINUTES',
        help='a lone in-process run saves its state between episodes this often, and an interrupted one '
        f'continues from there when the command runs again (default {Settings.save_every_s / 60:g}; 0: never)',
    )


@contextlib.contextmanager
def stopping_like_ctrl_c():
    """Inside: SIGTERM and SIGHUP (a closed terminal) end this command as Ctrl-C does, so that
    its pool stops its workers. With the default handlers the command died at once and left
    them running, orphaned, in the run folders. A second signal while stopping is ignored with
    one line, so that it cannot cut the stopping short. SIGINT is left ignored where the shell
    ignores it (a command started in the background). The handlers before are restored after."""

    def again(signum, frame):
        print(f'{signal.Signals(signum).name} again: already stopping', file=sys.stderr, flush=True)

    def first(signum, frame):
        for sig in signals:
            signal.signal(sig, again)
        raise KeyboardInterrupt

    signals = [signal.SIGTERM, signal.SIGHUP]
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signals.append(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread():
        signals = []  # Python takes signals in its main thread only
    previous = {sig: signal.getsignal(sig) for sig in signals}
    for sig in signals:
        signal.signal(sig, first)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


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
    parser.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument('--episodes', type=int, help='episodes per run (default: max_episodes of the file)')
    parser.add_argument('--max-steps', type=int, help='steps per episode (default: from the file)')
    parser.add_argument('--budget', type=int, help='early-advising budget in episodes')
    parser.add_argument('--expert', choices=(*EXPERT_BACKENDS, 'none'), help='expert backend')
    parser.add_argument('--policy-path', help='policy file for --expert policy')
    parser.add_argument('--output', required=True, help='output folder')
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1, help='parallel runs')
    parser.add_argument('--through-ros', action='store_true', help='run through the ROS nodes')
    parser.add_argument(
        '--eval-every',
        type=int,
        default=10,
        help='every N episodes (and after the last), the deterministic policy alone, without advice, from '
        'fixed start states; written to eval.csv (in-process runs; 0: none)',
    )
    parser.add_argument('--eval-starts', type=int, default=10, help='start states of each evaluation')
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
    return parser.parse_args(argv)


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
                'eval_every': settings.eval_every,
                'eval_starts': settings.eval_starts,
                'params_file': settings.params_path,
                'learner': settings.learner,
            }
        )
    )

    todo = [(a, s) for a in args.algorithms for s in args.seeds if not (run_dir(output, a, s) / 'DONE').exists()]
    skipped = len(args.algorithms) * len(args.seeds) - len(todo)
    together = not args.through_ros and (
        args.seeds_together or (not args.seeds_apart and seeds_together_by_default(settings))
    )
    jobs = max(1, min(args.jobs, len(todo) or 1))
    print(
        f'{settings.env_id or settings.env_node}: {len(todo)} runs to do ({skipped} finished already), '
        f'{settings.episodes} episodes x {settings.max_episode_steps} steps, {args.jobs} in parallel, '
        f'{"through ROS" if args.through_ros else "in-process"}'
        f'{", seeds together" if together else ""}',
        flush=True,
    )
    count, start = EpisodeCount(len(todo) * settings.episodes), time.monotonic()
    last_print = 0.0
    progress = progress_queue(args.cluster)
    try:
        with stopping_like_ctrl_c(), run_pool(jobs, args.cluster) as pool:
            if together:
                # Each algorithm's seeds in `jobs` shares, one process each, a share's seeds together.
                groups = []
                for algorithm in args.algorithms:
                    seeds = [s for a, s in todo if a == algorithm]
                    groups += [(algorithm, seeds[i::jobs]) for i in range(jobs) if seeds[i::jobs]]
                tasks = [
                    (len(seeds), pool.apply_async(_group_worker, (settings, a, seeds, output, progress)))
                    for a, seeds in groups
                ]
            else:
                tasks = [
                    (
                        1,
                        pool.apply_async(
                            run_worker, (settings, a, s, run_dir(output, a, s), args.through_ros, progress, d)
                        ),
                    )
                    for (a, s), d in zip(todo, domain_ids(len(todo)))
                ]
            finished_tasks = 0
            while finished_tasks < len(tasks):
                try:
                    count.add(progress.get(timeout=0.5))
                except queue.Empty:
                    pass
                newly = sum(r.ready() for _, r in tasks) - finished_tasks
                for _, r in tasks:
                    if r.ready() and not r.successful():
                        r.get()  # re-raise a worker's error here
                finished_tasks += newly
                now = time.monotonic()
                if now - last_print > 15.0 or newly:
                    last_print = now
                    runs_done = sum((run_dir(output, a, s) / 'DONE').exists() for a, s in todo)
                    if args.cluster:  # no episode reports across hosts: finished runs only
                        print(f'[{runs_done}/{len(todo)} runs, {(now - start) / 60:.1f} min]', flush=True)
                    else:
                        print(count.line(runs_done, len(todo), now - start), flush=True)
    except KeyboardInterrupt:
        print('\ninterrupted: finished runs are kept; run the same command to continue', file=sys.stderr)
        gather(output, args.algorithms, args.seeds)
        return 130
    except ClusterUnavailable as error:
        print(f'eqhrl-experiment: {error}', file=sys.stderr)
        return 2
    path = gather(output, args.algorithms, args.seeds)
    print(f'all runs finished in {(time.monotonic() - start) / 60:.1f} min; episodes in {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
