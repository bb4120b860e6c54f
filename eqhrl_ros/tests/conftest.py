"""Test isolation: every test run talks ROS only to itself.

Set before rclpy is imported anywhere: a private ROS domain derived from the
process id, and localhost-only discovery, so that two runs on one machine (or a
run beside a real robot) never hear each other. Child processes inherit both.
Under pytest-xdist (make test runs two workers) the domain comes from the run's
process and the worker's index, so that the workers of one run never share one.
"""

import os


def _private_domain() -> int:
    """1..100, valid on every platform: one domain per test process."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')  # 'gw0', 'gw1', … (set before conftest is read)
    if not worker.startswith('gw'):
        return 1 + os.getpid() % 100
    # The workers are children of the run's pytest: its pid picks a block, the index a domain in it.
    block, index = os.getppid() % 25, int(worker[2:])
    return 1 + (block * 4 + index) % 100


os.environ['ROS_DOMAIN_ID'] = str(_private_domain())
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')  # pygame renders rgb_array frames without a display

import contextlib  # noqa: E402
import fcntl  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)
# The real `ros2` CLI and `ros2 launch` (not on PyPI): `make test` builds them here from
# ../shared/ros2-tools where that exists (the project's machines); a user's clone has none.
ROS2_TOOLS = REPO / '.ros2-tools' / 'setup.sh'

# Two cores: keep torch from oversubscribing when tests start ROS node threads.
torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _alone_if_marked(request, tmp_path_factory):
    """Under pytest-xdist, a test marked ``alone`` (it asserts wall-clock timing) runs with no
    other worker's test beside it. Without xdist there is one test at a time anyway."""
    if 'PYTEST_XDIST_WORKER' not in os.environ:
        yield
        return
    with _run_lock(tmp_path_factory, exclusive=request.node.get_closest_marker('alone') is not None):
        yield  # released after the test's teardown


@contextlib.contextmanager
def _run_lock(tmp_path_factory, exclusive):
    """The run's lock, over all its xdist workers: each test (and the colcon build) holds it
    shared, an ``alone`` test exclusive. The turnstile lets a waiting ``alone`` test in before
    the next shared holder. POSIX record locks (lockf), which belong to the worker process: a
    child that a test forks and leaves behind does not hold them, as it held flock's."""
    run_folder = tmp_path_factory.getbasetemp().parent  # above each worker's own basetemp
    with open(run_folder / 'tests.turnstile', 'a+') as turnstile, open(run_folder / 'tests.lock', 'a+') as lock:
        fcntl.lockf(turnstile, fcntl.LOCK_EX)
        fcntl.lockf(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)  # exclusive: waits for the others
        fcntl.lockf(turnstile, fcntl.LOCK_UN)
        yield  # both are released when the files close


@pytest.fixture
def ros_context():
    """A private rclpy context, shut down after the test whatever happens."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def harness(ros_context, request):
    """Nodes spun by one executor in the test thread; all destroyed after the test.

    The executor is rclpy's SingleThreadedExecutor unless a test parametrizes
    ``harness`` indirectly with another kind ('events', 'multi')."""
    from ros_helpers import Harness

    h = Harness(ros_context, getattr(request, 'param', 'single'))
    try:
        yield h
    finally:
        h.close()


@pytest.fixture(scope='session')
def colcon_install(tmp_path_factory):
    """The repository built as a ROS user builds it: a checkout under src/ of a workspace,
    `colcon build`, the venv as underlay. Returns the install space.

    Under pytest-xdist the workers of a run share one build: the first that needs it makes it
    while the others wait on a lock (two builds at once would take both cores for a minute)."""
    if 'PYTEST_XDIST_WORKER' not in os.environ:
        return _colcon_build(tmp_path_factory.mktemp('ws'))
    run_folder = tmp_path_factory.getbasetemp().parent  # above each worker's own basetemp
    workspace = run_folder / 'colcon_ws'
    with open(run_folder / 'colcon_ws.lock', 'a+') as lock:
        fcntl.lockf(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (workspace / 'install').is_dir():
            shutil.rmtree(workspace, ignore_errors=True)  # what a failed build left
            workspace.mkdir()
            with _run_lock(tmp_path_factory, exclusive=False):  # a session fixture: not under a test's lock
                return _colcon_build(workspace)
    return workspace / 'install'


def _colcon_build(workspace):
    colcon = VENV / 'bin' / 'colcon'
    if not colcon.exists():
        pytest.fail(f'colcon is missing from {VENV}: run `make setup`')
    (workspace / 'src').mkdir()
    # Build outputs at the top only (a pattern would also drop eqhrl_ros/core/runs), caches anywhere.
    top = {'.venv', '.ros2-tools', 'build', 'install', 'log', 'runs', '.git'}
    caches = shutil.ignore_patterns('__pycache__', '*.egg-info')

    def ignore(folder, names):
        return set(caches(folder, names)) | (top & set(names) if Path(folder) == REPO else set())

    shutil.copytree(REPO, workspace / 'src' / 'eqhrl', ignore=ignore)
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
    if result.returncode != 0:
        shutil.rmtree(workspace / 'install', ignore_errors=True)  # so that no other worker takes it
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return workspace / 'install'


@pytest.fixture(scope='session')
def ros2_env(colcon_install):
    """The environment of a shell that sourced the real ros2 tools and the colcon install space,
    as a ROS user's terminal has it (this test run's private domain included)."""
    if not ROS2_TOOLS.is_file():
        pytest.skip(f'no real ros2 CLI here ({ROS2_TOOLS} missing: make test installs it from ../shared/ros2-tools)')
    script = f'. {ROS2_TOOLS} && . {colcon_install}/setup.sh && env -0'
    result = subprocess.run(['bash', '-c', script], capture_output=True, timeout=60, check=True)
    pairs = (item.split('=', 1) for item in result.stdout.decode().split('\0') if '=' in item)
    return dict(pairs)
