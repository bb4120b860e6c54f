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


def test_the_shipped_plan_loads_and_names_every_group(capsys):
    plan = study.load_plan('pendulum')
    groups = list(dict.fromkeys(a.group for a in plan.arms))
    assert groups == ['main', 'learning_starts', 'experts', 'budget', 'queue', 'ablations', 'temperature']
    main = [a for a in plan.arms if a.group == 'main']
    assert len(main[0].seeds) >= 10 and {a.mode for a in main} == {'sac', 'qasac', 'eqsac', 'random'}
    for arm in plan.arms:
        study.arm_settings(plan, arm)  # every arm's settings are ones the learner accepts


def test_the_lunar_lander_plan_has_the_papers_budget_inside_its_episodes():
    plan = study.load_plan('lunar_lander')
    for arm in plan.arms:
        settings = study.arm_settings(plan, arm)
        assert settings.env_id == 'LunarLanderContinuous-v3' and study.budget_of(settings) == 300
    assert plan.episodes > 300 and len(plan.arms[0].seeds) >= 3


def test_each_advising_arm_is_measured_against_the_sac_arm_that_learns_as_it_does():
    from eqhrl_ros.cli.study_report import ArmInfo, comparisons

    arms = [
        ArmInfo('sac', 'SAC', 'main', 'sac', ''),
        ArmInfo('eqsac', 'EQSAC', 'main', 'eqsac', ''),
        ArmInfo('sac_ls256', 'SAC', 'ls', 'sac', '', {'learning_starts': 256}),
        ArmInfo('eqsac_ls256', 'EQSAC', 'ls', 'eqsac', '', {'learning_starts': 256}),
        ArmInfo('random_ls256', 'random', 'ls', 'random', 'eqsac_ls256', {'learning_starts': 256}),
        ArmInfo('eqsac_b10', 'EQSAC', 'budget', 'eqsac', '', {'advising_budget': 10}),
        ArmInfo('eqsac_alpha', 'EQSAC', 'alpha', 'eqsac', '', {'initial_alpha': 0.1}),
    ]
    assert comparisons(arms) == [
        ('eqsac', 'sac', 'vs SAC'),
        ('eqsac_ls256', 'sac_ls256', 'vs SAC'),
        ('eqsac_ls256', 'random_ls256', 'vs random, matched'),
        ('random_ls256', 'sac_ls256', 'vs SAC'),
        ('eqsac_b10', 'sac', 'vs SAC'),  # SAC never reads the budget
    ]  # no SAC learns with initial_alpha 0.1 here: no comparison rather than a wrong one


def test_a_groups_figure_shows_the_arms_it_is_measured_against_from_other_groups():
    from eqhrl_ros.cli.study_report import ArmInfo, curve_arms

    arms = [  # the LunarLander plan's shape: the baselines apart from the pair they are measured against
        ArmInfo('sac', 'SAC', 'main', 'sac', ''),
        ArmInfo('eqsac', 'EQSAC', 'main', 'eqsac', ''),
        ArmInfo('random', 'random', 'baselines', 'random', 'eqsac'),
        ArmInfo('qasac', 'QASAC', 'baselines', 'qasac', ''),
    ]
    assert [a.name for a in curve_arms(arms, 'baselines')] == ['sac', 'eqsac', 'random', 'qasac']
    assert [a.name for a in curve_arms(arms, 'main')] == ['sac', 'eqsac']


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


def test_a_finished_runs_time_gives_the_lists_estimate(tmp_path):
    import os
    import time

    run = tmp_path / 'arm' / 'seed0'
    run.mkdir(parents=True)
    (run / 'STARTED').touch()
    os.utime(run / 'STARTED', (time.time() - 120, time.time() - 120))
    (run / 'DONE').touch()  # a mark without its seconds: the marks' times
    assert study.run_minutes(run) == pytest.approx(2.0, abs=0.05)
    assert study.run_minutes(tmp_path / 'missing') is None


def test_a_cloned_runs_time_comes_from_its_done_mark_not_the_files_times(tmp_path):
    run = tmp_path / 'arm' / 'seed0'
    run.mkdir(parents=True)
    (run / 'STARTED').touch()  # a clone or a copy: both marks written at the same moment
    (run / 'DONE').write_text('90.0\n')  # as run_worker writes it: the run's seconds
    assert study.run_minutes(run) == pytest.approx(1.5)


def test_the_effort_frontier_places_each_gate_against_chance_at_its_request_count(tmp_path):
    from eqhrl_ros.cli.study_report import ArmInfo, RunScores, frontier, frontier_table, plot_frontier

    def arm(name, mode, **learner):
        return ArmInfo(name, name, 'g', mode, '', learner)

    arms = [
        arm('sac', 'sac'),
        arm('r1', 'random', random_ask_rate=0.01),
        arm('r4', 'random', random_ask_rate=0.04),
        arm('gate', 'eqsac'),
        arm('greedy', 'qasac'),  # asks more than every frontier arm: left unplaced
    ]
    # Per seed: SAC scores s; chance gains +2 at 10 requests and +6 at 40; the gate gains 8 at 20,
    # where the frontier (linear in log requests) gains 2 + 4 * log(2)/log(4) = 4: above it by 4.
    scores = {}
    for seed in range(6):
        base = 10.0 * seed
        for name, asked, gain in (('sac', 0, 0), ('r1', 10, 2), ('r4', 40, 6), ('gate', 20, 8), ('greedy', 400, 1)):
            noise = 0.1 * ((seed * 7 + len(name)) % 3 - 1)  # the differences vary a little by seed
            scores[(name, seed)] = RunScores(0.0, base + gain + noise * (name != 'sac'), 0.0, asked, asked, 0.0, {})
    line, placed = frontier(arms, scores)
    assert [p.arm.name for p in line] == ['r1', 'r4']
    by_name = {p.arm.name: p for p in placed}
    n, mean, low, high, p = by_name['gate'].above
    assert n == 6 and abs(mean - 4.0) < 0.2 and low > 3.0 and p < 0.05
    assert by_name['greedy'].above is None
    table = frontier_table(arms, scores)
    assert 'outside its range' in table and '| gate | 6 | 20 |' in table
    assert plot_frontier(arms, scores, tmp_path / 'frontier.png') and (tmp_path / 'frontier.png').stat().st_size > 0
    assert frontier(arms[:2] + arms[3:], scores)[0] == [line[0]] and not frontier_table(arms[:2] + arms[3:], scores)
