"""tools/random_prior.py: the control for a prior of advice is loaded as that prior is."""

import importlib.util
from pathlib import Path

import numpy as np


def _tool():
    path = Path(__file__).resolve().parents[3] / 'tools' / 'random_prior.py'
    spec = importlib.util.spec_from_file_location('random_prior', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_random_prior_loads_as_advice_does_with_its_count_actions_and_episode_ends(tmp_path):
    from eqhrl_ros.files.mcap_record import load_prior

    output = tmp_path / 'random' / 'record.mcap'
    _tool().main(['--env', 'Pendulum-v1', '--episode-steps', '20', '--transitions', '47', '--output', str(output)])
    prior = load_prior([tmp_path / 'random'], 3, [-2.0], [2.0])
    assert len(prior) == 47
    assert np.all(np.abs(prior.actions) <= 1.0) and prior.actions.std() > 0.3  # spread over [-1, 1]
    assert np.all((prior.rewards <= 0.0) & (prior.rewards >= -16.3))  # Pendulum's reward range
    # Within an episode each transition starts where the last one ended; at 20 steps the env resets.
    chained = np.all(np.isclose(prior.observations[1:], prior.next_observations[:-1]), axis=1)
    assert not chained[19] and not chained[39] and chained[:19].all() and chained[20:39].all()
    assert not prior.terminated.any()  # Pendulum only truncates


def test_the_same_seed_gives_the_same_prior_and_another_seed_another(tmp_path):
    from eqhrl_ros.files.mcap_record import load_prior

    tool = _tool()
    for name, seed in (('a', 3), ('b', 3), ('c', 4)):
        tool.main(['--transitions', '10', '--seed', str(seed), '--output', str(tmp_path / name / 'record.mcap')])
    a, b, c = (load_prior([tmp_path / name], 3, [-2.0], [2.0]) for name in 'abc')
    assert np.array_equal(a.actions, b.actions) and np.array_equal(a.observations, b.observations)
    assert not np.array_equal(a.actions, c.actions)


def test_bad_counts_are_refused_in_one_line_and_write_nothing(tmp_path, capsys):
    import pytest

    tool = _tool()
    for argv, why in (
        (['--transitions', '0'], '--transitions must be at least 1'),
        (['--transitions', '5', '--episode-steps', '0'], '--episode-steps must be at least 1'),
    ):
        with pytest.raises(SystemExit):
            tool.main([*argv, '--output', str(tmp_path / 'record.mcap')])
        assert why in capsys.readouterr().err
    assert not (tmp_path / 'record.mcap').exists()
