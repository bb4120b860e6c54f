"""OpenMP's spin: eqhrl_ros leaves libgomp's own (the thread count is fitted to the machine instead,
core/algorithm/cpu_threads.py); a short spin set here would make every quiet update wake its
worker a dozen times. A user's value reaches OpenMP unchanged."""

import os
import subprocess
import sys

SCRIPT = (
    'import os, sys; import eqhrl_ros; assert "torch" not in sys.modules; '
    'import eqhrl_ros.core.algorithm.learner; print(os.environ.get("GOMP_SPINCOUNT", "unset"))'
)


def run(env_value=None) -> str:
    env = {k: v for k, v in os.environ.items() if k != 'GOMP_SPINCOUNT'}
    if env_value is not None:
        env['GOMP_SPINCOUNT'] = env_value
    done = subprocess.run([sys.executable, '-c', SCRIPT], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_the_spin_is_libgomps_own_and_a_users_setting_reaches_openmp():
    assert run() == 'unset'
    assert run('1000') == '1000'
