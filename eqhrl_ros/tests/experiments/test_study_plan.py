"""A study's plan (experiments/study_plan.py) and what its runs say about themselves (study_runs.py)."""

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


def test_the_lunar_lander_plan_has_the_papers_budget_inside_its_episodes():
    plan = study_plan.load_plan('lunar_lander')
    for arm in plan.arms:
        settings = study_plan.arm_settings(plan, arm)
        assert settings.env_id == 'LunarLanderContinuous-v3' and study_plan.budget_of(settings) == 300
    assert plan.episodes > 300 and len(plan.arms[0].seeds) >= 3


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
