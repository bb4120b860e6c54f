"""One fact, one home: each list of fields that appears in more than one place is generated from
its dataclass or checked here against it."""

import csv
import dataclasses
import io
import subprocess
import sys

from eqhrl_interfaces.msg import EpisodeStats, GateDecision
from eqhrl_ros.core.algorithm.advising import GateDecision as CoreGateDecision
from eqhrl_ros.core.data.summary import EpisodeSummary
from eqhrl_ros.core.runs.evaluation import EVAL_FIELDS, EvalEpisode
from eqhrl_ros.core.runs.trainer import TRAINER_CSV_FIELDS
from eqhrl_ros.experiments import gather, seed_runs

# How the message generator names the Python types of the dataclasses' fields.
MESSAGE_KINDS = {'int': ('int32', 'int64'), 'float': ('double',), 'bool': ('boolean',)}


def test_episode_stats_msg_episodes_csv_and_the_summary_hold_the_same_fields_in_one_order():
    fields = dataclasses.fields(EpisodeSummary)
    message = EpisodeStats.get_fields_and_field_types()
    assert list(message) == [f.name for f in fields]
    wrong = {f.name: (f.type, message[f.name]) for f in fields if message[f.name] not in MESSAGE_KINDS[f.type]}
    assert not wrong, wrong
    assert EpisodeSummary.CSV_FIELDS == tuple('return' if f.name == 'episode_return' else f.name for f in fields)
    assert TRAINER_CSV_FIELDS == (*EpisodeSummary.CSV_FIELDS, 'actor')


def test_an_episodes_csv_row_reads_back_as_the_summary_it_came_from():
    summary = EpisodeSummary(7, -123.456789, 100, 3, 2, 1, 1, 0, True, 700, 0.123456789, False, 1.5, 9.25, 1, 4, 0.75)
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(EpisodeSummary.CSV_FIELDS)
    writer.writerow(summary.csv_row())
    row = next(csv.DictReader(io.StringIO(text.getvalue())))
    for f in dataclasses.fields(EpisodeSummary):
        value, column = getattr(summary, f.name), row['return' if f.name == 'episode_return' else f.name]
        if f.type == 'float':
            assert abs(float(column) - value) < 1e-3, f.name
        else:
            assert int(column) == int(value), f.name


def test_the_gate_topic_and_gates_csv_take_their_fields_from_the_core_gate_decision():
    core = {f.name for f in dataclasses.fields(CoreGateDecision)}
    message = set(GateDecision.get_fields_and_field_types()) - {'episode', 'step'}
    assert message <= core, message - core
    assert set(seed_runs.GATE_COLUMNS) <= core
    assert seed_runs.GATE_FIELDS == ('episode', 'step', *seed_runs.GATE_COLUMNS)


def test_the_gathered_tables_name_columns_their_runs_write():
    assert gather.COLUMNS[:2] == ('algorithm', 'seed')
    assert set(gather.COLUMNS[2:]) <= set(EpisodeSummary.CSV_FIELDS)
    assert gather.EVAL_COLUMNS[:2] == ('algorithm', 'seed')
    assert set(gather.EVAL_COLUMNS[2:]) <= set(EVAL_FIELDS)
    assert len(EvalEpisode(1, 2, -3.0, 4, True).csv_row()) == len(EVAL_FIELDS)


def test_the_experiment_runner_reads_a_params_file_without_starting_ros():
    probe = (
        'import sys\n'
        'from eqhrl_ros.cli import experiment\n'
        'from eqhrl_ros.experiments.settings import learner_config, load_settings\n'
        "args = experiment.parse_args(['--params', 'pendulum', '--seeds', '0', '--output', '/tmp/unused'])\n"
        'settings = load_settings(args)\n'
        'learner_config(settings, "eqsac", 0)\n'
        "print(settings.env_id, sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces')))\n"
    )
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ['Pendulum-v1', '[]']


def test_the_summarys_advice_fields_and_the_learners_counts_map_both_ways_in_one_place():
    from eqhrl_ros.core.algorithm.advice_counts import SUMMARY_FIELDS, AdviceCounts

    assert set(SUMMARY_FIELDS) | {'advice_failed'} <= {f.name for f in dataclasses.fields(EpisodeSummary)}
    counts = AdviceCounts(asked=5, given=3, human=2, declined=1, human_time_s=4.5, takeovers=1, takeover_steps=7)
    counts.failed['timeout'] = 1
    fields = counts.summary_fields()
    assert fields['advice_asked'] == 5 and fields['advice_failed'] == 1 and fields['takeover_steps'] == 7
    summary = EpisodeSummary(
        episode=0, episode_return=0.0, length=10, success=False, total_steps=10, alpha=0.2, **fields
    )
    back = AdviceCounts.from_summary(summary)
    assert (back.asked, back.given, back.human, back.declined, back.human_time_s, back.takeover_steps) == (
        5,
        3,
        2,
        1,
        4.5,
        7,
    )
