"""The tree builds as a regular ROS 2 workspace does: colcon, with the venv as underlay
(the build is conftest.py's colcon_install, shared with the tests of the real ros2 CLI).

Checks what `ros2 run eqhrl_ros learner` relies on after sourcing install/setup.bash:
the ament index entry, executables in lib/eqhrl_ros, and the Advise type importable
from the install space.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # see setup.cfg: left out by make test-fast

VENV = sys.prefix


def test_colcon_builds_both_packages(colcon_install):
    index = colcon_install / 'eqhrl_ros' / 'share' / 'ament_index' / 'resource_index' / 'packages'
    assert (index / 'eqhrl_ros').is_file()
    assert (colcon_install / 'eqhrl_interfaces' / 'share' / 'eqhrl_interfaces' / 'srv' / 'Advise.srv').is_file()
    assert (colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'params' / 'pendulum.yaml').is_file()
    assert (colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / 'train.launch.py').is_file()


def test_the_install_space_holds_every_module_of_the_package(colcon_install):
    import eqhrl_ros

    source = Path(eqhrl_ros.__file__).parent
    installed = next((colcon_install / 'eqhrl_ros' / 'lib').glob('python3*/site-packages/eqhrl_ros'))
    modules = {p.relative_to(source) for p in source.rglob('*.py')}
    assert modules and modules <= {p.relative_to(installed) for p in installed.rglob('*.py')}


def test_ros2_run_finds_the_executables(colcon_install):
    lib = colcon_install / 'eqhrl_ros' / 'lib' / 'eqhrl_ros'
    for name in ('gym_env', 'learner', 'expert'):
        assert os.access(lib / name, os.X_OK), f'{name} missing from {lib}'


def test_install_space_provides_the_advise_type(colcon_install):
    script = (
        f'. {colcon_install}/setup.sh && {sys.executable} -c '
        '"import eqhrl_interfaces.srv as s, eqhrl_ros.core as c; '
        'print(s.Advise.__module__, s.__file__); print(c.__file__)"'
    )
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV))
    result = subprocess.run(['bash', '-c', script], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    srv_line, core_line = result.stdout.strip().splitlines()[-2:]
    assert str(colcon_install / 'eqhrl_interfaces') in srv_line
    assert str(colcon_install / 'eqhrl_ros') in core_line


def test_installed_executables_answer_help(colcon_install):
    # What `ros2 run eqhrl_ros learner --help` runs: the install space's script, its package.
    lib = colcon_install / 'eqhrl_ros' / 'lib' / 'eqhrl_ros'
    script = f'. {colcon_install}/setup.sh && {lib / "learner"} --help'
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV))
    result = subprocess.run(['bash', '-c', script], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith('usage: learner') and 'advising_budget' in result.stdout
