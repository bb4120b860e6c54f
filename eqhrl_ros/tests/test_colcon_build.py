"""The tree builds as a regular ROS 2 workspace does: colcon, with the venv as underlay.

Checks what `ros2 run eqhrl_ros learner` relies on after sourcing install/setup.bash:
the ament index entry, executables in lib/eqhrl_ros, and the Advise type importable
from the install space.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # see setup.cfg: left out by make test-fast

REPO = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    colcon = VENV / 'bin' / 'colcon'
    if not colcon.exists():
        pytest.fail(f'colcon is missing from {VENV}: run `make setup`')
    workspace = tmp_path_factory.mktemp('ws')
    (workspace / 'src').mkdir()
    # A checkout of this repository under src/, as a ROS user would have it (build outputs left out).
    shutil.copytree(
        REPO,
        workspace / 'src' / 'eqhrl',
        ignore=shutil.ignore_patterns('.venv', 'build', 'install', 'log', 'runs', '.git', '__pycache__', '*.egg-info'),
    )
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV))
    env['PATH'] = f'{VENV / "bin"}:{env["PATH"]}'
    result = subprocess.run(
        [
            str(colcon),
            'build',
            '--event-handlers',
            'console_direct-',
            '--cmake-args',
            f'-DPython3_EXECUTABLE={sys.executable}',
            f'-DCMAKE_PROJECT_INCLUDE={REPO / "tools" / "cmake" / "venv_underlay_fixes.cmake"}',
            '-DBUILD_TESTING=OFF',
        ],
        cwd=workspace,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return workspace / 'install'


def test_colcon_builds_both_packages(colcon_install):
    index = colcon_install / 'eqhrl_ros' / 'share' / 'ament_index' / 'resource_index' / 'packages'
    assert (index / 'eqhrl_ros').is_file()
    assert (colcon_install / 'eqhrl_interfaces' / 'share' / 'eqhrl_interfaces' / 'srv' / 'Advise.srv').is_file()
    assert (colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'params' / 'pendulum.yaml').is_file()
    assert (colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / 'train.launch.py').is_file()


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
