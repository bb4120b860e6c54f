"""One run of one seed, in this process: its env, learner, expert and record files, resumable between
episodes; or several seeds of one algorithm learning together (core/algorithm/stacked_seeds.py)."""

from __future__ import annotations

import dataclasses
import numbers
import time
from pathlib import Path

from ..core.runs.provenance import note_provenance
from .ros_runs import run_through_ros
from .settings import Settings, learner_config, make_expert


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
    prior = settings.learner.get('prior') or []
    if prior and not resumed:  # a resumed run's saved memories hold it already
        load_prior_into(learner, prior)
    # Resumed after episode E: episodes 0..E-1, evaluations after up to E episodes, and the
    # gates of episodes 0..E-1 are kept; later rows are made again.
    keep = learner.episode if resumed else None
    record = EpisodeRecord(directory / 'episodes.csv', EpisodeSummary.CSV_FIELDS, keep)  # the learner node's record
    if record.gap_warning:
        print(record.gap_warning, flush=True)
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
        if settings.learner.get('record'):
            write_advice_record(directory, learner, env.action_space)
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


def load_prior_into(learner, sources) -> int:
    """Earlier runs' advised transitions into D and D_advising (the learner node's prior)."""
    from ..files.mcap_record import load_prior

    prior = load_prior(sources, learner.obs_dim, learner.scaler.low, learner.scaler.high)
    return learner.add_prior(
        prior.observations, prior.actions, prior.rewards, prior.next_observations, prior.terminated
    )


def write_advice_record(directory: Path, learner, action_space) -> None:
    """An in-process run's record: its advised transitions (D_advising at the end, in the order
    stored while it was not full) as one TransitionBatch in <run>/record.mcap, what --prior
    reads. (A learner node's record holds much more: README, "The record".)"""
    from ..core.data.replay import BATCH_COLUMNS
    from ..files.mcap_record import RECORD_NAME

    memory, n = learner.advice_replay, len(learner.advice_replay)
    columns = [getattr(memory, name)[:n].numpy() for name in BATCH_COLUMNS]
    write_transitions_record(directory / RECORD_NAME, columns, action_space)


def write_transitions_record(path: Path, columns: list, action_space) -> None:
    """Transitions (BATCH_COLUMNS: observations, actions in [-1, 1], rewards, next observations,
    terminated) as one TransitionBatch marked advised, in the .mcap file ``path``: what --prior
    loads into D and D_advising."""
    import numpy as np

    from ..core.data.transitions import TransitionBatch, batch_fields
    from ..files.mcap_record import McapRecord

    n = len(columns[2])
    batch = TransitionBatch('in_process', 0, *columns[:4], np.asarray(columns[4]) > 0.5, np.ones(n, bool))
    record = McapRecord(path)
    try:
        fields = batch_fields(batch, action_space.low, action_space.high)
        record.write_fields('/learner/transitions', 'eqhrl_interfaces/msg/TransitionBatch', fields)
    finally:
        record.close()


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

    from ..core.runs.in_process import train_stacked

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
        train_stacked(runs, settings.episodes)
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


def run_worker(settings, algorithm, seed, directory, through_ros, progress, domain_id) -> tuple:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / 'DONE').unlink(missing_ok=True)
    start = time.monotonic()
    if through_ros:  # the learner node notes what made it (core/runs/provenance.py)
        run_through_ros(settings, algorithm, seed, directory, progress, domain_id)
        elapsed = time.monotonic() - start
    else:
        note_provenance(directory)
        elapsed = run_in_process(settings, algorithm, seed, directory, progress, domain_id)
    (directory / 'DONE').write_text(f'{elapsed:.1f}\n')
    if not through_ros:
        from ..core.runs.resume_point import remove_files

        remove_files(directory)  # after DONE: a run killed in between is not redone
    return algorithm, seed, elapsed


def group_worker(settings, algorithm, seeds, output, progress) -> tuple:
    """Seeds of one algorithm together in this process (run_together)."""
    for seed in seeds:
        directory = run_dir(output, algorithm, seed)
        directory.mkdir(parents=True, exist_ok=True)
        (directory / 'DONE').unlink(missing_ok=True)
        note_provenance(directory)
    start = time.monotonic()
    run_together(settings, algorithm, seeds, output, progress)
    return algorithm, tuple(seeds), time.monotonic() - start
