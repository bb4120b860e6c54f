"""eqhrl-experiment and eqhrl-report on tiny settings and synthetic data with known values."""

import csv
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from eqhrl_ros.cli import experiment, report
from eqhrl_ros.core.data.summary import EpisodeSummary
from eqhrl_ros.core.runs.records import EpisodeRecord, RunFolder
from eqhrl_ros.experiments import gather, seed_runs
from eqhrl_ros.experiments.settings import load_settings
from eqhrl_ros.reports import run_report


def read(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def tiny_run(output, *extra):
    return experiment.main(
        [
            '--params',
            'demo',
            '--algorithms',
            'sac',
            'eqsac',
            '--seeds',
            '0',
            '1',
            '--episodes',
            '2',
            '--max-steps',
            '15',
            '--jobs',
            '2',
            '--output',
            str(output),
            *extra,
        ]
    )


@pytest.mark.slow
def children_of_this_process() -> set:
    """Live child processes of this one, but multiprocessing's resource tracker (one per
    process, started by the first spawn and kept on purpose)."""
    found = set()
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
            command = Path(f'/proc/{pid}/cmdline').read_bytes()
        except OSError:
            continue
        if int(stat[1]) == os.getpid() and stat[0] != 'Z' and b'resource_tracker' not in command:
            found.add(int(pid))
    return found


def test_runner_writes_the_documented_columns_and_resume_skips_finished_runs(tmp_path, capsys):
    before = children_of_this_process()
    assert tiny_run(tmp_path) == 0
    # Its progress queue's Manager was forked and outlived the command, with this process's open
    # files and locks (it held the test run's lock and stopped the other xdist worker).
    assert children_of_this_process() - before == set()
    rows = read(tmp_path / 'episodes.csv')
    assert tuple(rows[0].keys()) == gather.COLUMNS
    assert len(rows) == 2 * 2 * 2
    assert {(r['algorithm'], r['seed']) for r in rows} == {('sac', '0'), ('sac', '1'), ('eqsac', '0'), ('eqsac', '1')}
    assert all(int(r['length']) == 15 for r in rows)
    assert all(int(r['advice_asked']) == 0 for r in rows if r['algorithm'] == 'sac')
    # The advice-free evaluation, by default after every 10th and the last episode: here after
    # episode 2, from the same 10 start states for every run.
    evals = read(tmp_path / 'eval.csv')
    assert tuple(evals[0].keys()) == gather.EVAL_COLUMNS
    assert len(evals) == 4 * 10 and {r['episode'] for r in evals} == {'2'}
    starts = {(r['algorithm'], r['seed']): [] for r in evals}
    for r in evals:
        starts[(r['algorithm'], r['seed'])].append(int(r['start']))
    assert len({tuple(v) for v in starts.values()}) == 1

    finished = tmp_path / 'sac' / 'seed0' / 'episodes.csv'
    kept_mtime = finished.stat().st_mtime_ns
    (tmp_path / 'eqsac' / 'seed1' / 'DONE').unlink()  # as if interrupted during this run
    capsys.readouterr()
    assert tiny_run(tmp_path) == 0
    assert '1 runs to do (3 finished already)' in capsys.readouterr().out
    assert finished.stat().st_mtime_ns == kept_mtime
    assert len(read(tmp_path / 'episodes.csv')) == 8


def write_synthetic(folder):
    """SAC: constant returns -100 (seed 0) and -300 (seed 1), no advice.
    EQSAC: returns -500 for 20 episodes then 0 for 20; one piece of advice in each of
    the first 5 episodes (seed 0) or first 3 (seed 1); success from episode 20 on."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'settings.yaml').write_text('env_id: Pendulum-v1\n')
    with open(folder / 'episodes.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(gather.COLUMNS)
        for seed, level in ((0, -100.0), (1, -300.0)):
            for episode in range(40):
                writer.writerow(['sac', seed, episode, level, 100, 0, 0, 0])
        for seed, advised in ((0, 5), (1, 3)):
            for episode in range(40):
                ret = -500.0 if episode < 20 else 0.0
                given = 1 if episode < advised else 0
                writer.writerow(
                    ['eqsac', seed, episode, ret, 100, given + 1 if given else 0, given, int(episode >= 20)]
                )


def test_report_table_shows_the_known_values(tmp_path):
    write_synthetic(tmp_path / 'runs')
    table = {row['algorithm']: row for row in run_report.summarize(run_report.read_runs([tmp_path / 'runs']), -200.0)}
    sac, eqsac = table['sac'], table['eqsac']
    assert sac['final_return'] == pytest.approx((-200.0, 100.0))
    assert sac['advice_given'] == (0.0, 0.0) and sac['reached'] == 1  # only seed 0 is above -200
    assert eqsac['advice_given'] == pytest.approx((4.0, 1.0))
    assert eqsac['advice_asked'] == pytest.approx((8.0, 2.0))
    assert eqsac['final_return'] == pytest.approx((0.0, 0.0))
    assert eqsac['final_success'] == pytest.approx((1.0, 0.0))
    assert eqsac['success'] == pytest.approx((0.5, 0.0))
    assert eqsac['reached'] == 2 and 17 <= eqsac['episodes_to_threshold'][0] <= 21
    text = run_report.format_table(list(table.values()), -200.0)
    assert '| EQSAC | 2 | 40 | 4 ± 1 | 8 ± 2 | 0.0 ± 0.0 | 100 ± 0 % | 50 ± 0 % |' in text
    # One run has no spread: its value alone (before: '± 0', as if two runs had agreed).
    reached = [line for line in text.splitlines() if '(1 of 2 runs reached it)' in line]
    assert len(reached) == 1 and '±' not in reached[0].split('|')[-2], reached
    runs = run_report.read_runs([tmp_path / 'runs'])
    one = run_report.summarize({key: run for key, run in runs.items() if key[1] == 0}, -200.0)
    assert '±' not in run_report.format_table(one, -200.0).splitlines()[2]


def test_report_command_writes_table_and_figures(tmp_path):
    write_synthetic(tmp_path / 'runs')
    assert report.main([str(tmp_path / 'runs'), '--output', str(tmp_path / 'out')]) == 0
    assert 'EQSAC' in (tmp_path / 'out' / 'table.md').read_text()
    for name in ('returns.png', 'advice.png', 'success.png', 'advice_heatmap.png'):
        data = (tmp_path / 'out' / name).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 5000, name
    assert not (tmp_path / 'out' / 'eval_returns.png').exists()  # no eval.csv, no figure


def test_the_return_to_reach_is_the_envs_own_or_said_to_be_none(tmp_path, capsys):
    """Before (2026-12-05) a report of the double integrator counted episodes to a return of 0,
    unsaid: 0 is no threshold of that env's."""
    said: list = []
    assert run_report.return_threshold('Pendulum-v1', say=said.append) == -200.0
    assert run_report.return_threshold('MountainCarContinuous-v0', say=said.append) == 90.0  # gymnasium's own
    assert run_report.return_threshold('double_integrator_env', -5.0, say=said.append) == -5.0 and said == []
    assert run_report.return_threshold('double_integrator_env', say=said.append) == 0.0
    assert said == [
        "double_integrator_env has no return threshold of its own: 'episodes to return ≥ 0' counts to 0 "
        '(give --threshold)'
    ]
    write_synthetic(tmp_path / 'runs')
    (tmp_path / 'runs' / 'settings.yaml').write_text('env_id: double_integrator_env\n')
    assert report.main([str(tmp_path / 'runs'), '--output', str(tmp_path / 'out')]) == 0
    assert 'double_integrator_env has no return threshold of its own' in capsys.readouterr().err


def test_report_reads_single_runs_by_the_mode_seed_and_env_their_learner_noted(tmp_path, capsys):
    """From outside: `eqhrl-report runs/pendulum` on a run of eqhrl-train or ros2 launch (no
    algorithm and seed columns) ended in a KeyError traceback."""

    def single_run(folder, returns, **about):
        RunFolder(folder).begin(**about)
        record = EpisodeRecord(folder / 'episodes.csv', EpisodeSummary.CSV_FIELDS)
        for episode, value in enumerate(returns):
            row = dict.fromkeys(EpisodeSummary.CSV_FIELDS, 0)
            record.append([{**row, 'episode': episode, 'return': value, 'length': 100}[k] for k in row])
        return folder

    runs = [
        single_run(tmp_path / 'a', [-900.0, -100.0], env='Pendulum-v1', mode='sac', seed=1),
        single_run(tmp_path / 'b', [-800.0, -300.0], env='Pendulum-v1', mode='sac', seed=2),
        single_run(tmp_path / 'c', [-700.0, -50.0], env='Pendulum-v1', mode='eqsac', seed=1),
        single_run(tmp_path / 'older', [-600.0, -600.0]),  # before the learner noted its mode
    ]
    assert sorted(run_report.read_runs(runs)) == [('eqsac', 1), ('older', 0), ('sac', 1), ('sac', 2)]
    assert report.main([*map(str, runs), '--output', str(tmp_path / 'out')]) == 0
    table = (tmp_path / 'out' / 'table.md').read_text()
    assert '| SAC | 2 | 2 |' in table and '| EQSAC | 1 | 2 |' in table and '| older | 1 | 2 |' in table
    assert 'episodes to return ≥ -200' in table  # Pendulum's, from the runs' provenance
    twin = single_run(tmp_path / 'again', [-1.0], env='Pendulum-v1', mode='sac', seed=1)
    assert report.main([str(runs[0]), str(twin), '--output', str(tmp_path / 'out2')]) == 1
    assert f'{runs[0]} and {twin} both hold sac seed 1' in capsys.readouterr().err


def test_report_reads_the_advice_free_evaluation(tmp_path):
    write_synthetic(tmp_path / 'runs')
    with open(tmp_path / 'runs' / 'eval.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(gather.EVAL_COLUMNS)
        for algorithm, base in (('sac', -400.0), ('eqsac', -300.0)):
            for seed in (0, 1):
                for episode in (10, 20):
                    for start in range(3):  # seed 1 is 100 better; later evaluations 50 better
                        writer.writerow(
                            [algorithm, seed, episode, start, base + 100 * seed + 2.5 * episode + start, 100, 0]
                        )
    evals = run_report.read_eval([tmp_path / 'runs'])
    assert evals['eqsac'][10] == pytest.approx([-274.0, -174.0])  # each seed's mean over its 3 starts
    assert evals['sac'][20] == pytest.approx([-349.0, -249.0])
    assert report.main([str(tmp_path / 'runs'), '--output', str(tmp_path / 'out')]) == 0
    assert (tmp_path / 'out' / 'eval_returns.png').read_bytes()[:4] == b'\x89PNG'


@pytest.mark.parametrize(
    'program,arguments,message',
    [
        ('experiment', ['--seeds', '-1'], 'argument --seeds: LearnerConfig.seed must be in [0'),
        ('experiment', ['--budget', '-2'], 'argument --budget: LearnerConfig.advising_budget must be in [0'),
        ('experiment', ['--episodes', '-5'], 'argument --episodes: -5 is below 1'),
        ('experiment', ['--max-steps', '0'], 'argument --max-steps: 0 is below 1'),
        ('experiment', ['--jobs', '0'], 'argument --jobs: 0 is below 1'),
        ('study', ['--plan', 'pendulum', '--max-seeds', '0'], 'argument --max-seeds: 0 is below 1'),
        ('train', ['--seed', 'x'], "argument --seed: 'x' is not an integer"),
        ('train', ['--budget-s', '-5'], 'argument --budget-s: LearnerConfig.advising_budget_s must be in [0'),
    ],
)
def test_command_line_values_are_checked_by_meaning_as_a_usage_error(program, arguments, message, capsys):
    """Before: eqhrl-experiment --seeds -1 (or --budget -2) ended in a worker's traceback, and
    --episodes -5 ran nothing and said 'all runs finished'; --jobs 0 and --max-steps 0 ran anyway."""
    from eqhrl_ros.cli import study, train

    parse = {'experiment': experiment.parse_args, 'study': study.parse_args, 'train': train.parse_args}[program]
    with pytest.raises(SystemExit) as ended:
        parse([*arguments, '--output', 'x'] if program != 'train' else arguments)
    assert ended.value.code == 2 and message in capsys.readouterr().err


def test_report_refuses_a_folder_without_results(tmp_path, capsys):
    assert report.main([str(tmp_path), '--output', str(tmp_path / 'out')]) == 1
    assert 'no episodes.csv' in capsys.readouterr().err


def test_episodes_to_reach_is_nan_when_never_reached():
    assert math.isnan(run_report.episodes_to_reach(np.full(30, -500.0), -200.0))


@pytest.mark.slow
@pytest.mark.alone  # its runs take ROS domains of their own (domain_ids): maybe the other worker's
def test_in_process_and_through_ros_give_the_same_numbers(tmp_path):
    """Lock-step ROS runs the same algorithm on the same seed: the same episodes, with the
    same advice, and returns equal up to float32 rounding of rewards in the messages."""
    params_file = tmp_path / 'tiny.yaml'
    params_file.write_text(
        'gym_env:\n  ros__parameters:\n    env_id: Pendulum-v1\n    max_episode_steps: 30\n'
        'expert:\n  ros__parameters:\n    backend: heuristic\n    env_id: Pendulum-v1\n'
        'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n    hidden_sizes: [16, 16]\n'
        '    batch_size: 16\n    learning_starts: 20\n    queue_length: 3\n    advising_budget: 2\n'
        '    max_episodes: 3\n'
    )
    common = ['--params', str(params_file), '--algorithms', 'eqsac', '--seeds', '5', '--jobs', '1']
    assert experiment.main([*common, '--output', str(tmp_path / 'core')]) == 0
    assert experiment.main([*common, '--through-ros', '--output', str(tmp_path / 'ros')]) == 0
    core, ros = read(tmp_path / 'core' / 'episodes.csv'), read(tmp_path / 'ros' / 'episodes.csv')
    assert len(core) == len(ros) == 3
    for a, b in zip(core, ros):
        assert (a['episode'], a['length'], a['advice_asked'], a['advice_given']) == (
            b['episode'],
            b['length'],
            b['advice_asked'],
            b['advice_given'],
        )
        assert float(a['return']) == pytest.approx(float(b['return']), rel=1e-3)
    assert sum(int(r['advice_given']) for r in core) > 0


@pytest.mark.slow
def test_seeds_together_write_what_seeds_apart_write(tmp_path, capsys):
    """Three seeds in one process learning together: each seed's episodes, advice and
    advice-free evaluation as a process of its own gives them (to float rounding)."""
    params_file = tmp_path / 'tiny.yaml'
    params_file.write_text(
        'gym_env:\n  ros__parameters:\n    env_id: Pendulum-v1\n    max_episode_steps: 40\n'
        'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n    hidden_sizes: [32, 32]\n'
        '    batch_size: 32\n    learning_starts: 40\n    queue_length: 3\n    advising_budget: 2\n'
        '    max_episodes: 3\n'
    )
    common = ['--params', str(params_file), '--algorithms', 'eqsac', '--seeds', '0', '1', '2', '--eval-every', '2']
    assert seed_runs.seeds_together_by_default(load_settings(experiment.parse_args(common + ['--output', 'x'])))
    assert experiment.main([*common, '--jobs', '1', '--output', str(tmp_path / 'together')]) == 0
    assert 'seeds together' in capsys.readouterr().out
    assert experiment.main([*common, '--jobs', '2', '--seeds-apart', '--output', str(tmp_path / 'apart')]) == 0
    assert 'seeds together' not in capsys.readouterr().out
    for name in ('episodes.csv', 'eval.csv'):
        together, apart = read(tmp_path / 'together' / name), read(tmp_path / 'apart' / name)
        assert len(together) == len(apart) > 0
        for a, b in zip(together, apart):
            assert float(a['return']) == pytest.approx(float(b['return']), rel=1e-4)
            assert {k: v for k, v in a.items() if k != 'return'} == {k: v for k, v in b.items() if k != 'return'}
    assert sum(int(r['advice_given']) for r in read(tmp_path / 'together' / 'episodes.csv')) > 0
    assert all((tmp_path / 'together' / 'eqsac' / f'seed{s}' / 'DONE').exists() for s in range(3))


@pytest.mark.parametrize(
    'extra,message', [(['--through-ros'], 'runs in-process'), (['--params', 'PROPORTIONAL'], "advice_batch 'full'")]
)
def test_seeds_together_that_cannot_be_had_are_refused_before_anything_runs(tmp_path, capsys, extra, message):
    params = tmp_path / 'p.yaml'
    params.write_text('learner:\n  ros__parameters:\n    hidden_sizes: [16, 16]\n    advice_batch: proportional\n')
    extra = [str(params) if word == 'PROPORTIONAL' else word for word in extra]
    args = ['--params', 'demo', '--seeds', '0', '--episodes', '1', '--seeds-together', '--output', str(tmp_path / 'o')]
    assert experiment.main(args + extra) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()
    if '--through-ros' not in extra:  # by default such settings simply run apart
        settings = load_settings(experiment.parse_args(['--params', str(params), '--output', 'x']))
        assert not seed_runs.seeds_together_by_default(settings)


def test_a_params_file_for_the_example_env_node_never_runs_pendulum_in_its_place(tmp_path, capsys):
    """From outside: `eqhrl-experiment --params double_integrator` (in-process) and an eqhrl-study
    plan with `params: double_integrator` ran Pendulum-v1, silently (the report was titled so); and
    through ROS, where the example env did run, the command said and saved 'Pendulum-v1'."""
    from eqhrl_ros.cli import study
    from eqhrl_ros.nodes.double_integrator_env_node import PARAMETERS
    from eqhrl_ros.parameters import GYM_ENV_PARAMS, default_of

    refused = 'double_integrator.yaml is for the env node double_integrator_env, which is no gymnasium env'
    args = ['--params', 'double_integrator', '--seeds', '0', '--episodes', '1', '--output', str(tmp_path / 'o')]
    assert experiment.main(args) == 2 and refused in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()
    plan = tmp_path / 'plan.yaml'
    plan.write_text(
        'name: di\nparams: double_integrator\nepisodes: 2\ngroups:\n  - name: g\n    seeds: [0]\n'
        '    arms:\n      sac: {mode: sac}\n'
    )
    assert study.main(['--plan', str(plan), '--output', str(tmp_path / 's'), '--list']) != 0
    assert refused in capsys.readouterr().err
    through = load_settings(experiment.parse_args(['--params', 'double_integrator', '--through-ros', '--output', 'x']))
    assert through.env_id == '' and through.file_env_node == 'double_integrator_env'
    assert through.max_episode_steps == 100  # the file's double_integrator_env section
    # A named gymnasium env runs in-process with the file's learner settings.
    named = load_settings(
        experiment.parse_args(['--params', 'double_integrator', '--env', 'Pendulum-v1', '--output', 'x'])
    )
    assert named.env_id == 'Pendulum-v1' and named.learner['advising_budget'] == 10
    # With no section setting it, the episode length passed to eqhrl-train is either env node's own default.
    default_steps = {name: default for name, default, *_ in PARAMETERS}['max_episode_steps']
    assert default_steps == default_of(GYM_ENV_PARAMS, 'max_episode_steps')


def test_table_1_networks_run_seeds_apart_by_default():
    settings = load_settings(experiment.parse_args(['--params', 'pendulum', '--output', 'x']))
    assert not seed_runs.seeds_together_by_default(settings)
    settings = load_settings(experiment.parse_args(['--params', 'demo', '--output', 'x']))
    assert seed_runs.seeds_together_by_default(settings)


# ------------------------------------------------------------------ one reading path for params files


@pytest.mark.parametrize(
    'line,message',
    [
        ('    gama: 0.9', "unknown parameter(s) for node 'learner': gama"),
        ('    tau: 2.0', "'tau' of node 'learner' is 2.0"),
        ('    batch_size: 64.0', "'batch_size' of node 'learner' is 64.0"),
    ],
)
def test_the_experiment_refuses_a_params_file_as_the_learner_node_does(tmp_path, capsys, line, message):
    params = tmp_path / 'bad.yaml'
    params.write_text(f'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n{line}\n')
    assert (
        experiment.main(['--params', str(params), '--output', str(tmp_path / 'out'), '--seeds', '0', '--episodes', '1'])
        == 2
    )
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


class _Interrupt(Exception):
    """Stands in for a kill: the run ends in the middle, without closing anything."""


class _Progress:
    """The runner's progress queue; ``stop_at``: the episode whose report ends the run."""

    def __init__(self, stop_at=None):
        self.episodes, self.stop_at = [], stop_at

    def put(self, item):
        _, _, episode, _ = item
        self.episodes.append(episode)
        if episode == self.stop_at:
            raise _Interrupt


def test_an_interrupted_run_continues_from_its_last_save_and_writes_what_an_uninterrupted_one_writes(tmp_path):
    """A run killed after episode 3 resumes from its save after episode 2: it does not start
    over, and its episodes, evaluations and gate records are the uninterrupted run's, row for
    row (the learner with its replay memories, the env's start states and a simulated
    person's noise and misses all continue where they were)."""
    import torch

    params_file = tmp_path / 'tiny.yaml'
    params_file.write_text(
        'gym_env:\n  ros__parameters:\n    env_id: Pendulum-v1\n    max_episode_steps: 40\n'
        'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n    hidden_sizes: [32, 32]\n'
        '    batch_size: 32\n    learning_starts: 40\n    queue_length: 3\n    advising_budget: 5\n'
        '    max_episodes: 6\n'
    )
    args = experiment.parse_args(['--params', str(params_file), '--eval-every', '2', '--output', 'x'])
    settings = load_settings(args)
    settings.save_every_s = 1e-9  # after every episode
    settings.gate_trace = True
    settings.expert_options = {'human': {'action_noise': 0.3, 'miss_probability': 0.3}}
    threads = torch.get_num_threads()
    try:
        whole, cut = tmp_path / 'whole', tmp_path / 'cut'
        for folder in (whole, cut):
            folder.mkdir()
        seed_runs.run_in_process(settings, 'eqsac', 3, whole, _Progress())

        with pytest.raises(_Interrupt):
            seed_runs.run_in_process(settings, 'eqsac', 3, cut, _Progress(stop_at=3))
        assert (cut / 'resume.pt').exists() and (cut / 'resume-replay.pt').exists()
        progress = _Progress()
        seed_runs.run_in_process(settings, 'eqsac', 3, cut, progress)
    finally:
        torch.set_num_threads(threads)
    assert progress.episodes == [3, 4, 5]  # episodes 0-2 were not run again
    for name in ('episodes.csv', 'eval.csv', 'gates.csv'):
        assert (cut / name).read_text() == (whole / name).read_text(), name
    rows = read(whole / 'episodes.csv')
    assert sum(int(r['advice_given']) for r in rows) > 0 and sum(int(r['advice_failed']) for r in rows) > 0


def test_a_save_of_another_run_is_not_resumed(tmp_path, capsys):
    """A resume point made with other settings is reported and removed; the run starts over."""
    import torch

    from eqhrl_ros.core.runs.resume_point import CHECKPOINT

    args = experiment.parse_args(['--params', 'demo', '--episodes', '3', '--max-steps', '15', '--output', 'x'])
    settings = load_settings(args)
    settings.save_every_s = 1e-9
    threads = torch.get_num_threads()
    try:
        with pytest.raises(_Interrupt):
            seed_runs.run_in_process(settings, 'sac', 0, tmp_path, _Progress(stop_at=1))
        assert (tmp_path / CHECKPOINT).exists()
        settings.episodes = 4  # another run's settings in the same folder
        progress = _Progress()
        seed_runs.run_in_process(settings, 'sac', 0, tmp_path, progress)
    finally:
        torch.set_num_threads(threads)
    assert 'not resumed (it was saved by a run with other settings); the run starts over' in capsys.readouterr().out
    assert progress.episodes == [0, 1, 2, 3]
    assert [r['episode'] for r in read(tmp_path / 'episodes.csv')] == ['0', '1', '2', '3']


def test_save_every_refuses_a_negative_interval(capsys):
    assert experiment.main(['--save-every', '-1', '--output', 'x']) == 2
    assert '--save-every must be >= 0 minutes' in capsys.readouterr().err


def test_a_resume_point_that_cannot_be_written_costs_the_save_not_the_run(tmp_path, capsys, monkeypatch):
    """A full disk at a save: one line, the run goes on to its end."""
    import torch

    from eqhrl_ros.core.data.errors import CheckpointWriteError
    from eqhrl_ros.core.runs import resume_point

    def full_disk(*args, **kwargs):
        raise CheckpointWriteError('resume.pt: No space left on device')

    monkeypatch.setattr(resume_point, 'save_checkpoint', full_disk)
    args = experiment.parse_args(['--params', 'demo', '--episodes', '3', '--max-steps', '15', '--output', 'x'])
    settings = load_settings(args)
    settings.save_every_s = 1e-9
    threads = torch.get_num_threads()
    progress = _Progress()
    try:
        seed_runs.run_in_process(settings, 'sac', 0, tmp_path, progress)
    finally:
        torch.set_num_threads(threads)
    assert progress.episodes == [0, 1, 2]
    assert capsys.readouterr().out.count('could not save the resume point') == 3


def _children(pid):
    """Live (not zombie) processes whose parent is ``pid``."""
    found = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            text = stat.read_text()
        except OSError:
            continue
        state, ppid = text.rsplit(')', 1)[1].split()[:2]
        if int(ppid) == pid and state != 'Z':
            found.append(int(stat.parent.name))
    return found


def _alive(pid):
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state != 'Z'


def _stop_and_check_workers_end(command, tmp_path, sig):
    log = open(tmp_path / 'log.txt', 'w+')
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
    workers = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.5)
            workers = [p for p in _children(process.pid) if 'spawn_main' in Path(f'/proc/{p}/cmdline').read_text()]
        assert len(workers) >= 2, 'the pool never started'
        # The workers are training: a run has finished episodes.
        while time.monotonic() < deadline and not any(
            len(path.read_text().splitlines()) > 1 for path in tmp_path.rglob('seed*/episodes.csv')
        ):
            time.sleep(0.2)
        workers = _children(process.pid)  # and the Manager's server and multiprocessing's resource tracker
        process.send_signal(sig)
        assert process.wait(timeout=60) == 130  # as after Ctrl-C
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        assert not any(_alive(p) for p in workers), 'processes left running after the command ended'
        log.seek(0)
        assert 'interrupted: finished runs are kept' in log.read()
    finally:
        if process.poll() is None:
            process.kill()
        for pid in {*workers, *_children(process.pid)}:  # orphans too, should the test fail
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP], ids=['SIGTERM', 'SIGHUP'])
def test_a_terminated_experiment_stops_its_workers_with_it(tmp_path, sig):
    """kill PID or a closed terminal: the pool's workers end with the command, not orphaned in the run folders."""
    command = [str(Path(sys.prefix) / 'bin' / 'eqhrl-experiment'), '--params', 'demo', '--algorithms', 'sac']
    command += ['--seeds', '0', '1', '--episodes', '500', '--seeds-apart', '--jobs', '2', '--output', 'out']
    _stop_and_check_workers_end(command, tmp_path, sig)


def test_a_terminated_study_stops_its_workers_with_it(tmp_path):
    (tmp_path / 'plan.yaml').write_text(
        'name: tiny\nparams: demo\nepisodes: 500\ngroups:\n  - name: main\n    seeds: [0, 1]\n'
        '    arms:\n      sac: {mode: sac}\n'
    )
    command = [str(Path(sys.prefix) / 'bin' / 'eqhrl-study'), '--plan', 'plan.yaml', '--jobs', '2', '--output', 'out']
    _stop_and_check_workers_end(command, tmp_path, signal.SIGTERM)


def test_a_recorded_experiment_seeds_the_next_with_its_advice(tmp_path, capsys):
    """--record keeps each in-process run's advised transitions; --prior puts all of them into
    the next runs' D and D_advising (seen here in the record the next run writes in turn)."""
    from eqhrl_ros.files.mcap_record import load_prior

    params_file = tmp_path / 'tiny.yaml'
    params_file.write_text(
        'gym_env:\n  ros__parameters:\n    env_id: Pendulum-v1\n    max_episode_steps: 30\n'
        'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n    hidden_sizes: [16, 16]\n'
        '    batch_size: 16\n    learning_starts: 30\n    queue_length: 3\n    advising_budget: 2\n'
        '    max_episodes: 3\n'
    )
    common = ['--params', str(params_file), '--algorithms', 'eqsac', '--eval-every', '0', '--jobs', '1']
    assert experiment.main([*common, '--seeds', '0', '1', '--record', '--output', str(tmp_path / 'first')]) == 0
    given = sum(int(row['advice_given']) for row in read(tmp_path / 'first' / 'episodes.csv'))
    assert given > 0
    first = load_prior([tmp_path / 'first'], 3, [-2.0], [2.0])
    assert len(first) == given and len(first.files) == 2

    second = ['--seeds', '5', '--record', '--prior', str(tmp_path / 'first'), '--output', str(tmp_path / 'second')]
    assert experiment.main([*common, *second]) == 0
    own = sum(int(row['advice_given']) for row in read(tmp_path / 'second' / 'episodes.csv'))
    # The second run's D_advising: the first runs' advice, then its own.
    assert len(load_prior([tmp_path / 'second'], 3, [-2.0], [2.0])) == given + own

    wrong = tmp_path / 'wrong.yaml'
    wrong.write_text(params_file.read_text().replace('Pendulum-v1', 'MountainCarContinuous-v0'))
    refused = [
        '--params',
        str(wrong),
        '--seeds',
        '0',
        '--prior',
        str(tmp_path / 'first'),
        '--output',
        str(tmp_path / 'x'),
    ]
    capsys.readouterr()
    assert experiment.main(refused) == 2  # before anything runs
    assert 'recorded on observations of 3 and actions of 1 values; this env has 2 and 1' in capsys.readouterr().err
    assert not (tmp_path / 'x').exists()


def test_a_run_through_ros_carries_record_and_prior_to_the_learner(tmp_path):
    from eqhrl_ros.experiments.ros_runs import train_command
    from eqhrl_ros.files.mcap_record import McapRecord

    record = McapRecord(tmp_path / 'record.mcap')  # an empty record on Pendulum's spaces is a valid prior
    fields = {'observation_size': 3, 'action_low': [-2.0], 'action_high': [2.0]}
    record.write_fields('/learner/transitions', 'eqhrl_interfaces/msg/TransitionBatch', fields)
    record.close()
    args = experiment.parse_args(
        ['--params', 'demo', '--through-ros', '--record', '--prior', str(tmp_path), '--output', str(tmp_path / 'o')]
    )
    settings = load_settings(args)
    command = train_command(settings, 'eqsac', 3, tmp_path / 'o' / 'eqsac' / 'seed3')
    assert '--record' in command
    assert command[command.index('--prior') + 1 :][:1] == [str(tmp_path.resolve())]


def test_eqhrl_train_sets_the_persons_budget_in_seconds_and_the_protocol_checked_by_the_learners_rule(capsys):
    from eqhrl_ros.cli import train

    args = train.parse_args(['--params', 'teleop_pendulum', '--budget-s', '300', '--advice-protocol', 'answer'])
    values = {p.name: p.value for p in train.learner_overrides(args)}
    assert values['advising_budget_s'] == 300.0 and isinstance(values['advising_budget_s'], float)
    assert values['advice_protocol'] == 'answer'
    with pytest.raises(SystemExit):
        train.parse_args(['--budget-s', '-3'])
    assert 'advising_budget_s must be in [0' in capsys.readouterr().err
