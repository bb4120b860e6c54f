"""A study's scores, comparisons and frontier (reports/study_scores.py and the tables and figures made from them)."""


def test_each_advising_arm_is_measured_against_the_sac_arm_that_learns_as_it_does():
    from eqhrl_ros.reports.study_scores import ArmInfo, comparisons

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
    from eqhrl_ros.reports.study_figures import curve_arms
    from eqhrl_ros.reports.study_scores import ArmInfo

    arms = [  # the LunarLander plan's shape: the baselines apart from the pair they are measured against
        ArmInfo('sac', 'SAC', 'main', 'sac', ''),
        ArmInfo('eqsac', 'EQSAC', 'main', 'eqsac', ''),
        ArmInfo('random', 'random', 'baselines', 'random', 'eqsac'),
        ArmInfo('qasac', 'QASAC', 'baselines', 'qasac', ''),
    ]
    assert [a.name for a in curve_arms(arms, 'baselines')] == ['sac', 'eqsac', 'random', 'qasac']
    assert [a.name for a in curve_arms(arms, 'main')] == ['sac', 'eqsac']


def test_the_effort_frontier_places_each_gate_against_chance_at_its_request_count(tmp_path):
    from eqhrl_ros.reports.study_figures import plot_frontier
    from eqhrl_ros.reports.study_scores import ArmInfo, RunScores, frontier
    from eqhrl_ros.reports.study_tables import frontier_table

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


def test_the_placement_table_shows_whether_a_matched_arm_asked_as_clustered_as_its_reference(tmp_path):
    import csv

    from eqhrl_ros.reports.study_scores import ArmInfo
    from eqhrl_ros.reports.study_tables import clustered_share, placement_table

    assert clustered_share({0: [3, 4, 10], 1: [0]}) == 0.5  # 3 and 4 are near; 10 and 0 alone
    rows = []
    for seed in (0, 1):
        for step in range(20):
            rows.append(['eqsac', seed, 0, step, int(step in (5, 6, 7))])  # a clustered reference
            rows.append(['random', seed, 0, step, int(step in (1, 9, 15))])  # as many, spread out
    with (tmp_path / 'gates.csv').open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['arm', 'seed', 'episode', 'step', 'fire'])
        writer.writerows(rows)
    arms = [ArmInfo('eqsac', 'EQSAC', 'g', 'eqsac', ''), ArmInfo('random', 'random', 'g', 'random', 'eqsac')]
    table = placement_table(tmp_path, arms)
    assert '| random | eqsac | 2 | 6 / 6 | 2 of 2 | 100 % | 0 % |' in table


def test_a_torn_row_in_a_studys_table_is_one_line_naming_file_and_line(tmp_path, capsys):
    """Before, eqhrl-study-report met a row with fewer values than its header (a kill mid-write, a
    hand edit) deep in its tables, as a TypeError traceback."""
    import shutil
    from pathlib import Path

    from eqhrl_ros.cli.study_report import main

    study = Path(__file__).resolve().parents[3] / 'docs' / 'results' / 'study_lunar_lander_steps'
    shutil.copy(study / 'plan.yaml', tmp_path / 'plan.yaml')
    (tmp_path / 'arms.csv').write_text('arm,label,group,mode,seeds,learner,expert,match\nsac,SAC,main,sac\n')
    for name in ('episodes.csv', 'eval.csv'):
        (tmp_path / name).write_text('arm,seed,episode,return\n')
    assert main([str(tmp_path), '--output', str(tmp_path / 'report')]) == 2
    said = capsys.readouterr().err
    assert said == f'eqhrl-study-report: {tmp_path / "arms.csv"}, line 2: not one value for each of its columns\n'
