"""eqhrl-study and eqhrl-study-report: one resumable command for a study, and the
tables and figures made from its raw CSVs."""

import csv

import pytest
import yaml

from eqhrl_ros.cli import study, study_report

TINY = {
    'name': 'tiny',
    'params': 'pendulum',
    'episodes': 4,
    'max_steps': 40,
    'eval_every': 2,
    'eval_starts': 2,
    'learner': {
        'learning_starts': 60,
        'advising_budget': 3,
        'batch_size': 16,
        'hidden_sizes': [16, 16],
        'compile_update': False,  # pendulum.yaml compiles; these runs are seconds long
    },
    'groups': [
        {
            'name': 'main',
            'seeds': [0, 1],
            'arms': {
                'sac': {'mode': 'sac', 'label': 'SAC'},
                'qasac': {'mode': 'qasac', 'gate_trace': True},
                'random': {'mode': 'random', 'match': 'qasac'},
            },
        },
        {
            'name': 'experts',
            'seeds': [0],
            'arms': {'qasac_weak': {'mode': 'qasac', 'expert': {'gain': 0.3, 'delay_steps': 2}}},
        },
    ],
}


def write_plan(path, plan=TINY):
    path.write_text(yaml.safe_dump(plan, sort_keys=False))  # the order of arms is their priority
    return str(path)


def rows(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def test_a_study_runs_every_arm_matches_the_random_arm_resumes_and_reports(tmp_path, capsys):
    plan = write_plan(tmp_path / 'tiny.yaml')
    output = tmp_path / 'out'
    assert study.main(['--plan', plan, '--output', str(output), '--jobs', '2']) == 0
    for arm, seeds in (('sac', (0, 1)), ('qasac', (0, 1)), ('random', (0, 1)), ('qasac_weak', (0,))):
        for seed in seeds:
            assert (output / arm / f'seed{seed}' / 'DONE').exists()
    episodes = rows(output / 'episodes.csv')
    assert list(episodes[0]) == [
        'arm',
        'seed',
        'episode',
        'return',
        'length',
        'advice_asked',
        'advice_given',
        'success',
        'human_time_s',
        'takeover_steps',
        'takeover_s',
        'asked_steps',
    ]
    assert len(episodes) == 7 * 4
    assert {r['arm'] for r in rows(output / 'eval.csv')} == {'sac', 'qasac', 'random', 'qasac_weak'}
    gates = rows(output / 'gates.csv')
    assert {r['arm'] for r in gates} == {'qasac'} and len(gates) == 2 * 3 * 40  # every step inside the budget

    # The random arm asks, seed by seed, at the rate its matched arm asked inside the budget.
    for seed in (0, 1):
        asked = sum(int(r['advice_asked']) for r in episodes if r['arm'] == 'qasac' and r['seed'] == str(seed))
        match = yaml.safe_load((output / 'random' / f'seed{seed}' / 'match.yaml').read_text())
        assert match == {'matches': 'qasac', 'requests': asked, 'steps': 120, 'random_ask_rate': asked / 120}
    assert [r['arm'] for r in rows(output / 'arms.csv')] == ['sac', 'qasac', 'random', 'qasac_weak']

    capsys.readouterr()
    assert study.main(['--plan', plan, '--output', str(output)]) == 0  # nothing left: finished runs are kept
    assert '7 runs, 7 finished, 0 to do' in capsys.readouterr().out

    report = tmp_path / 'report'
    assert study_report.main([str(output), '--output', str(report)]) == 0
    table = (report / 'table.md').read_text()
    assert '| SAC | main | 2 |' in table
    assert '| qasac | random | 2 |' in table  # the matched comparison
    assert '| qasac_weak | SAC | 1 |' in table  # the expert is not a learner setting: the main SAC
    for name in ('eval_main.png', 'eval_experts.png', 'profile.png', 'effort.png', 'eval.csv', 'gates.csv'):
        assert (report / name).stat().st_size > 0


def test_list_shows_the_order_without_running(tmp_path, capsys):
    plan = write_plan(tmp_path / 'tiny.yaml')
    assert study.main(['--plan', plan, '--output', str(tmp_path / 'out'), '--list', '--max-seeds', '1']) == 0
    listed = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [(w[2], w[-1]) for w in listed] == [('sac', '0'), ('qasac', '0'), ('random', '0'), ('qasac_weak', '0')]
    assert not (tmp_path / 'out' / 'sac').exists()


@pytest.mark.parametrize(
    'change, message',
    [
        (lambda p: p['groups'][0]['arms'].update(x={'mode': 'fast'}), 'mode must be one of'),
        (
            lambda p: p['groups'][0]['arms'].update(x={'mode': 'sac', 'match': 'qasac'}),
            'match is for modes random and ask_random',
        ),
        (lambda p: p['groups'][0]['arms'].update(x={'mode': 'random', 'match': 'nope'}), 'not an arm'),
        (lambda p: p['groups'][1]['arms'].update(x={'mode': 'random', 'match': 'qasac_weak', 'sead': 1}), 'sead'),
        (lambda p: p['groups'][0]['arms']['sac'].update(learner={'learning_start': 5}), 'learning_start'),
        (lambda p: p['groups'][0]['arms']['sac'].update(expert={'gain': 2.0}), 'gain'),
        (lambda p: p.update(epsiodes=3), 'epsiodes'),
    ],
)
def test_a_bad_plan_is_refused_before_anything_runs(tmp_path, capsys, change, message):
    plan = yaml.safe_load(yaml.safe_dump(TINY, sort_keys=False))
    change(plan)
    path = write_plan(tmp_path / 'bad.yaml', plan)
    assert study.main(['--plan', path, '--output', str(tmp_path / 'out')]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


@pytest.mark.slow
def test_timing_matched_and_thinned_arms_and_the_pre_stated_tests(tmp_path):
    plan = {
        **TINY,
        'tests': {'metric': 'auc', 'margin': 5, 'primary': [['qasac', 'timed'], ['qasac', 'sac']]},
        'groups': [
            {
                'name': 'main',
                'seeds': [0, 1],
                'arms': {
                    'sac': {'mode': 'sac', 'label': 'SAC'},
                    'qasac': {'mode': 'qasac'},
                    'timed': {'mode': 'random', 'match': 'qasac', 'match_timing': 'episode'},
                    'thinned': {'mode': 'ask_random', 'match': 'timed', 'thins': 'qasac'},
                },
            }
        ],
    }
    output, report = tmp_path / 'out', tmp_path / 'report'
    assert (
        study.main(['--plan', write_plan(tmp_path / 'timed.yaml', plan), '--output', str(output), '--jobs', '2']) == 0
    )
    episodes = rows(output / 'episodes.csv')
    for seed in ('0', '1'):
        per_episode = {
            arm: [int(r['advice_asked']) for r in episodes if r['arm'] == arm and r['seed'] == seed][:3]
            for arm in ('qasac', 'timed')
        }
        assert per_episode['timed'] == per_episode['qasac'] and sum(per_episode['qasac']) > 0  # in every episode
        match = yaml.safe_load((output / 'timed' / f'seed{seed}' / 'match.yaml').read_text())
        assert match['random_ask_schedule'] == per_episode['qasac'] and match['random_ask_horizon'] == 40
        thinned = yaml.safe_load((output / 'thinned' / f'seed{seed}' / 'match.yaml').read_text())
        # ask_random's rate: the matched arm's requests over the thinned arm's (here the same number).
        assert thinned['requests'] == sum(per_episode['timed']) and thinned['thinned_requests'] == sum(
            per_episode['qasac']
        )
        assert thinned['random_ask_rate'] == pytest.approx(thinned['requests'] / thinned['thinned_requests'])
    assert study_report.main([str(output), '--output', str(report)]) == 0
    table = (report / 'table.md').read_text()
    assert '## Pre-stated tests' in table and '| primary | qasac − timed | 2 |' in table
    timing = table.split('## When the arms asked')[1]
    line = {row.split('|')[1].strip(): row for row in timing.splitlines() if row.startswith('| ')}
    assert line['qasac'].split('|')[4:6] == line['timed'].split('|')[4:6]  # before and after: the same counts


def test_the_reports_never_replace_a_report_unless_told(tmp_path, capsys):
    from eqhrl_ros.cli import report

    output = tmp_path / 'committed'
    output.mkdir()
    (output / 'table.md').write_text('the committed table\n')
    assert study_report.main([str(tmp_path), '--output', str(output)]) == 2
    assert report.main([str(tmp_path), '--output', str(output)]) == 2
    assert 'give --overwrite' in capsys.readouterr().err
    assert (output / 'table.md').read_text() == 'the committed table\n'
