"""gymnasium envs as the nodes make them."""

import os
import subprocess
import sys

RENDER = """
from eqhrl_ros.core.envs.gymnasium_envs import make_env
for env_id in ('Pendulum-v1', 'LunarLanderContinuous-v3'):
    env = make_env(env_id, render_mode='rgb_array')
    env.reset(seed=0)
    frame = env.render()
    print(env_id, frame.shape, int(frame.max()) > int(frame.min()))
"""


def test_frames_drawn_off_screen_print_no_display_error_in_a_container():
    """From outside: a launch with the person's page (gym_env publishes its frames) printed
    `[gym_env-1] error: XDG_RUNTIME_DIR is invalid or not set in the environment.` in a container,
    where that variable is unset: SDL's default video driver, for frames that need no window."""
    env = {k: v for k, v in os.environ.items() if k not in ('XDG_RUNTIME_DIR', 'SDL_VIDEODRIVER')}
    result = subprocess.run([sys.executable, '-c', RENDER], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split('\n')[:2] == [
        'Pendulum-v1 (500, 500, 3) True',
        'LunarLanderContinuous-v3 (400, 600, 3) True',
    ], result.stdout
    assert 'error' not in result.stderr.lower(), result.stderr
