"""The OpenMP spin default: set on import, before torch; a user's value wins."""

import os
import subprocess
import sys

SCRIPT = (
    'import os, sys; import eqhrl_ros; assert "torch" not in sys.modules; '
    'import eqhrl_ros.core.algorithm.learner; print(os.environ["GOMP_SPINCOUNT"])'
)


def run(env_value=None) -> str:
    env = {k: v for k, v in os.environ.items() if k != 'GOMP_SPINCOUNT'}
    if env_value is not None:
        env['GOMP_SPINCOUNT'] = env_value
    done = subprocess.run([sys.executable, '-c', SCRIPT], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_a_short_spin_is_the_default_and_a_users_setting_wins():
    assert run() == '1000'
    assert run('300000') == '300000'
