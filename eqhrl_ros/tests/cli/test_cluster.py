"""eqhrl-study and eqhrl-experiment --cluster: runs handed to a Dask cluster
give the folders and results of the local process pool."""

import csv

import pytest
import yaml

from eqhrl_ros.cli import experiment, study
from eqhrl_ros.experiments import run_pool

pytestmark = pytest.mark.slow

PLAN = {
    'name': 'tiny_cluster',
    'params': 'pendulum',
    'episodes': 3,
    'max_steps': 40,
    'eval_every': 3,
    'eval_starts': 2,
    'learner': {'learning_starts': 60, 'advising_budget': 2, 'batch_size': 16, 'hidden_sizes': [16, 16]},
    'groups': [
        {
            'name': 'main',
            'seeds': [0, 1],
            'arms': {
                'sac': {'mode': 'sac'},
                'qasac': {'mode': 'qasac'},
                'random': {'mode': 'random', 'match': 'qasac', 'match_timing': 'episode'},
            },
        }
    ],
}


def rows(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope='module')
def cluster():
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, memory_limit=0, dashboard_address=None
    ) as local:
        yield local.scheduler_address


def test_a_study_on_a_dask_cluster_gives_the_local_pools_results(tmp_path, cluster, capsys):
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(PLAN, sort_keys=False))
    local, remote = tmp_path / 'local', tmp_path / 'remote'
    assert study.main(['--plan', str(plan), '--output', str(local), '--jobs', '2']) == 0
    assert study.main(['--plan', str(plan), '--output', str(remote), '--cluster', cluster]) == 0
    assert 'on the Dask cluster at' in capsys.readouterr().out
    for name in ('episodes.csv', 'eval.csv'):
        assert rows(remote / name) == rows(local / name) and rows(local / name)
    for seed in (0, 1):  # the matched arm waited for its reference on the cluster too
        match = yaml.safe_load((remote / 'random' / f'seed{seed}' / 'match.yaml').read_text())
        assert match == yaml.safe_load((local / 'random' / f'seed{seed}' / 'match.yaml').read_text())
    capsys.readouterr()
    assert study.main(['--plan', str(plan), '--output', str(remote), '--cluster', cluster]) == 0
    assert '6 runs, 6 finished, 0 to do' in capsys.readouterr().out  # the same resumable layout


def test_an_experiment_on_a_dask_cluster_writes_every_run(tmp_path, cluster, capsys):
    output = tmp_path / 'out'
    argv = ['--params', 'pendulum', '--episodes', '2', '--max-steps', '30', '--algorithms', 'sac', 'eqsac']
    argv += ['--seeds', '0', '1', '--eval-every', '0', '--output', str(output), '--cluster', cluster]
    assert experiment.main(argv) == 0
    episodes = rows(output / 'episodes.csv')
    assert {(r['algorithm'], r['seed']) for r in episodes} == {(a, s) for a in ('sac', 'eqsac') for s in '01'}
    assert '[4/4 runs,' in capsys.readouterr().out  # progress in finished runs (no episode reports)


def test_an_unreachable_cluster_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(run_pool, 'CONNECT_TIMEOUT_S', 1.0)  # nothing listens: the wait is all it costs
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(PLAN, sort_keys=False))
    code = study.main(['--plan', str(plan), '--output', str(tmp_path / 'o'), '--cluster', 'tcp://127.0.0.1:9'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'no Dask scheduler reachable' in err[0]
