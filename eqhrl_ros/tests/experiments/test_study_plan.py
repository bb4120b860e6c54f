"""A study's plan (experiments/study_plan.py) and what its runs say about themselves (study_runs.py)."""

from pathlib import Path

import pytest

from eqhrl_ros.experiments import study_plan, study_runs


def test_the_shipped_plan_loads_and_names_every_group(capsys):
    plan = study_plan.load_plan('pendulum')
    groups = list(dict.fromkeys(a.group for a in plan.arms))
    assert groups == ['main', 'learning_starts', 'experts', 'budget', 'queue', 'ablations', 'temperature']
    main = [a for a in plan.arms if a.group == 'main']
    assert len(main[0].seeds) >= 10 and {a.mode for a in main} == {'sac', 'qasac', 'eqsac', 'random'}
    for arm in plan.arms:
        study_plan.arm_settings(plan, arm)  # every arm's settings are ones the learner accepts


@pytest.mark.parametrize('name', sorted(p.stem for p in (Path(__file__).parents[2] / 'studies').glob('*.yaml')))
def test_every_shipped_plan_loads_with_settings_the_learner_accepts(name):
    plan = study_plan.load_plan(name)
    assert plan.name == name and plan.arms
    for arm in plan.arms:
        study_plan.arm_settings(plan, arm)


def test_the_lunar_lander_plan_has_the_papers_budget_inside_its_episodes():
    plan = study_plan.load_plan('lunar_lander')
    for arm in plan.arms:
        settings = study_plan.arm_settings(plan, arm)
        assert settings.env_id == 'LunarLanderContinuous-v3' and study_plan.budget_of(settings) == 300
    assert plan.episodes > 300 and len(plan.arms[0].seeds) >= 3


def test_an_env_id_in_a_plans_learner_settings_is_the_env_its_runs_use(tmp_path):
    """From outside: a plan with `params: pendulum` and `learner: {env_id: LunarLanderContinuous-v3}`
    ran Pendulum-v1 (the env_id there was ignored), and one for the example env's params file could
    not be given a gymnasium env at all."""
    plan_file = tmp_path / 'plan.yaml'
    arms = 'groups:\n  - name: g\n    seeds: [0]\n    arms:\n      sac: {mode: sac}\n'
    for params in ('pendulum', 'double_integrator'):
        plan_file.write_text(
            f'name: p\nparams: {params}\nepisodes: 2\nlearner:\n  env_id: LunarLanderContinuous-v3\n{arms}'
        )
        plan = study_plan.load_plan(str(plan_file))
        assert study_plan.arm_settings(plan, plan.arms[0]).env_id == 'LunarLanderContinuous-v3', params


def test_a_finished_runs_time_gives_the_lists_estimate(tmp_path):
    import os
    import time

    run = tmp_path / 'arm' / 'seed0'
    run.mkdir(parents=True)
    (run / 'STARTED').touch()
    os.utime(run / 'STARTED', (time.time() - 120, time.time() - 120))
    (run / 'DONE').touch()  # a mark without its seconds: the marks' times
    assert study_runs.run_minutes(run) == pytest.approx(2.0, abs=0.05)
    assert study_runs.run_minutes(tmp_path / 'missing') is None


def test_a_cloned_runs_time_comes_from_its_done_mark_not_the_files_times(tmp_path):
    run = tmp_path / 'arm' / 'seed0'
    run.mkdir(parents=True)
    (run / 'STARTED').touch()  # a clone or a copy: both marks written at the same moment
    (run / 'DONE').write_text('90.0\n')  # as run_worker writes it: the run's seconds
    assert study_runs.run_minutes(run) == pytest.approx(1.5)


def test_a_step_matched_arm_takes_the_steps_its_reference_asked_at_from_its_gate_trace(tmp_path):
    import csv

    run = tmp_path / 'eqsac' / 'seed0'
    run.mkdir(parents=True)
    with (run / 'episodes.csv').open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['episode', 'advice_asked', 'length'])
        writer.writerows([[0, 2, 10], [1, 0, 8], [2, 1, 10]])
    with (run / 'gates.csv').open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['episode', 'step', 'fire'])
        writer.writerows([[0, s, int(s in (3, 4))] for s in range(10)] + [[1, s, 0] for s in range(8)])
        writer.writerows([[2, s, int(s == 9)] for s in range(10)])
    steps = study_runs.requested_steps(run, budget=2)  # episode 2 is past the budget
    assert steps == [10, 3, 4, -1, 8, -1]
    from eqhrl_ros.core.algorithm.advising import step_patterns

    assert step_patterns(tuple(steps)) == [(10, (3, 4)), (8, ())]


def test_a_step_matched_arm_needs_a_reference_with_a_gate_trace(tmp_path):
    plan = {
        'name': 'p',
        'params': 'pendulum',
        'episodes': 2,
        'groups': [
            {
                'name': 'g',
                'seeds': [0],
                'arms': {
                    'eqsac': {'mode': 'eqsac'},
                    'random': {'mode': 'random', 'match': 'eqsac', 'match_timing': 'steps'},
                },
            }
        ],
    }
    import yaml

    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    with pytest.raises(ValueError, match='gate_trace'):
        study_plan.load_plan(str(path))
    plan['groups'][0]['arms']['eqsac']['gate_trace'] = True
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    assert [a.match_timing for a in study_plan.load_plan(str(path)).arms] == ['rate', 'steps']


def test_a_seed_given_twice_is_refused_by_a_plan_and_by_eqhrl_experiment(tmp_path, capsys):
    """One seed of one arm is one run folder: given twice, the run ran once and its rows were
    gathered twice (400 rows of 200 episodes in episodes.csv)."""
    import yaml

    from eqhrl_ros.cli.experiment import parse_args

    plan = {
        'name': 'p',
        'params': 'pendulum',
        'episodes': 2,
        'groups': [{'name': 'g', 'seeds': [0, 1, 0], 'arms': {'sac': {'mode': 'sac'}}}],
    }
    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    with pytest.raises(ValueError, match="group 'g': seed 0 appears twice"):
        study_plan.load_plan(str(path))
    for argv, said in (
        (['--seeds', '1', '2', '1'], 'argument --seeds: 1 given more than once'),
        (['--algorithms', 'sac', 'eqsac', 'sac'], 'argument --algorithms: sac given more than once'),
    ):
        with pytest.raises(SystemExit) as refused:
            parse_args(['--output', str(tmp_path / 'out'), *argv])
        assert refused.value.code == 2 and said in capsys.readouterr().err
    assert parse_args(['--output', str(tmp_path / 'out'), '--seeds', '1', '2']).seeds == [1, 2]
