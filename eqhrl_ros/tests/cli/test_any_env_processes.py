"""A user's env node that is not gymnasium, as users run it: separate processes."""

import statistics

import pytest

from eqhrl_ros.cli import experiment
from eqhrl_ros.experiments import ros_runs

from process_helpers import output, read_rows, start, stop, wait_for
from ros_helpers import PARAMS_DIR

pytestmark = pytest.mark.slow


def test_learner_and_expert_started_first_wait_for_the_example_env_then_learn(tmp_path):
    """`learner` and `expert` with no gymnasium id, then `double_integrator_env`: both wait for
    env_info, then the learner learns with the PD expert's advice. The margin: the median return
    of episodes 25-29 is above -50 and no worse than that of episodes 0-4 (a random policy scores
    about -580, the PD expert about -4; seed 1 of the shipped params file gave -87 and -6: advised
    first episodes can already be good, so a fixed gain over them is no measure of learning)."""
    out = tmp_path / 'run'
    params = ['--ros-args', '--params-file', str(PARAMS_DIR / 'double_integrator.yaml')]
    learner = start('learner', *params, '-p', f'output_dir:={out}', '-p', 'shutdown_when_done:=true', log_dir=tmp_path)
    expert = start('expert', *params, log_dir=tmp_path)
    env = None
    try:
        assert wait_for(lambda: 'waiting for env_info on /env_info' in output(learner), 30), output(learner)
        assert wait_for(lambda: 'waiting for env_info on /env_info' in output(expert), 30), output(expert)
        env = start('double_integrator_env', *params, log_dir=tmp_path)
        assert wait_for(lambda: learner.poll() is not None, 240), output(learner)
        assert learner.returncode == 0, output(learner)
    finally:
        logs = {name: stop(p) for name, p in (('learner', learner), ('expert', expert), ('env', env)) if p}
    assert "serving 'advise' with double_integrator_pd" in logs['expert']
    assert 'eqsac on double_integrator (env_info' in logs['learner']
    rows = read_rows(out / 'episodes.csv')
    returns = [float(r['return']) for r in rows]
    assert len(rows) == 30 and all(int(r['length']) == 100 for r in rows)
    first, last = statistics.median(returns[:5]), statistics.median(returns[25:])
    assert last >= -50 and last >= first, (first, last, returns)
    # Every request is counted. The learner's first observation waited for the expert to serve
    # 'advise' (start_wait.py): a CI run before that wait had all 10 advised episodes go by while the
    # expert was still being found, every request failed or declined.
    keys = ('advice_asked', 'advice_given', 'advice_declined', 'advice_failed')
    total = {key: sum(int(r[key]) for r in rows) for key in keys}
    assert total['advice_given'] > 0
    assert total['advice_given'] + total['advice_declined'] + total['advice_failed'] == total['advice_asked']
    assert all(int(r['advice_asked']) == 0 for r in rows[10:])  # advising_budget 10
    assert sum(int(r['success']) for r in rows) > 0  # the env reports its verdict


@pytest.mark.alone  # its runs take ROS domains of their own (domain_ids): maybe the other worker's
def test_the_experiment_runner_drives_a_users_env_node_by_command(tmp_path, capsys):
    params = tmp_path / 'di.yaml'
    params.write_text(
        (PARAMS_DIR / 'double_integrator.yaml')
        .read_text()
        .replace('max_episodes: 30', 'max_episodes: 3')
        .replace('learning_starts: 500', 'learning_starts: 50')
    )
    common = ['--params', str(params), '--algorithms', 'sac', 'qasac', '--seeds', '4', '--jobs', '2']
    command = 'double_integrator_env --ros-args -p seed:={seed} -p max_episode_steps:={max_steps}'
    assert (
        experiment.main(
            [*common, '--through-ros', '--max-steps', '20', '--env-node', command, '--output', str(tmp_path / 'out')]
        )
        == 0
    )
    rows = read_rows(tmp_path / 'out' / 'episodes.csv')
    assert sorted({r['algorithm'] for r in rows}) == ['qasac', 'sac'] and len(rows) == 6
    assert all(int(r['length']) == 20 for r in rows)
    assert sum(int(r['advice_given']) for r in rows if r['algorithm'] == 'qasac') > 0
    assert 'double_integrator: lock-step' in (tmp_path / 'out' / 'sac' / 'seed4' / 'env_node.log').read_text()
    assert experiment.main([*common, '--env-node', command, '--output', str(tmp_path / 'x')]) == 2
    assert '--env-node runs an env node, so it needs --through-ros' in capsys.readouterr().err
    # An env node that exits with an error: one line naming its log, not the worker's traceback (before).
    failing = 'double_integrator_env --ros-args -p seed:=-1'
    arguments = ['--params', str(params), '--algorithms', 'sac', '--seeds', '4', '--through-ros']
    assert experiment.main([*arguments, '--env-node', failing, '--output', str(tmp_path / 'y')]) == 1
    said = capsys.readouterr().err
    assert f'eqhrl-experiment: the env node exited (1) for sac seed 4; see {tmp_path / "y" / "sac" / "seed4"}' in said
    assert 'Traceback' not in said


def test_parallel_runs_of_one_experiment_never_share_a_ros_domain():
    """Two runs in one domain hear each other's env (a learner saw another run's observations
    before this rule). Each run gets its own domain, valid on every platform."""
    ids = ros_runs.domain_ids(100)
    assert len(set(ids)) == 100 and all(1 <= i <= 100 for i in ids)
