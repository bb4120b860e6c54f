"""A real-time env keeps its rate inside eqhrl-train while the learner updates.

The env, the expert and the learner each have their own executor and thread: a 100-step
episode at 15 Hz takes 100/15 = 6.7 s, the first episode included (its clock starts when
the learner is there), and every episode has its full length. Before, with one executor for
all, a 200-step episode took 44 s once updates began (13.3 s due), and the first was one step short.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from process_helpers import read_rows

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # its rate, not the other worker's load

STAMP = re.compile(r'\[INFO\] \[(\d+\.\d+)\] \[(\w+)\]: (.*)')


def test_a_real_time_episode_keeps_its_rate_with_updates_on(tmp_path):
    params = tmp_path / 'realtime.yaml'
    params.write_text(
        """
gym_env:
  ros__parameters:
    max_episode_steps: 100
    realtime: true
    rate_hz: 15.0
learner:
  ros__parameters:
    learning_starts: 50       # updates (256x256 networks) from the middle of episode 0 on
    advising_budget: 2
    max_episodes: 2
    advice_timeout_s: 0.5
/**:
  ros__parameters:
    env_id: Pendulum-v1
"""
    )
    out = tmp_path / 'run'
    done = subprocess.run(
        [str(Path(sys.prefix) / 'bin' / 'eqhrl-train'), '--params', str(params), '--output', str(out)],
        capture_output=True,
        text=True,
        timeout=180,
    )
    log = done.stdout + done.stderr
    assert done.returncode == 0, log
    rows = read_rows(out / 'episodes.csv')
    assert [int(r['length']) for r in rows] == [100, 100], log
    assert [r['interrupted'] for r in rows] == ['0', '0'], log
    assert 'does not follow' not in log  # no observation lost on the way
    events = [(float(t), node, text) for t, node, text in STAMP.findall(log)]
    first_step = next(t for t, node, text in events if node == 'gym_env' and text.startswith('first env step'))
    # The env's own line at each episode's last step: its clock, not the learner's log, which a
    # busy machine can delay (a rehearsal beside two training runs logged the learner's end of
    # episode 0 1.3 s late, episode 1 on time: 14.6 and 12.4 s, 27.0 together for 26.7).
    ends = [t for t, node, text in events if node == 'gym_env' and re.match(r'episode \d+: 100 steps', text)]
    assert len(ends) == 2, log
    period = 100 / 15.0
    # Episode 0 from its first step (its clock's first tick), episode 1 from the end of episode 0.
    durations = [ends[0] - first_step, ends[1] - ends[0]]
    assert durations == pytest.approx([period, period], rel=0.05), (durations, log)
