"""One run through the three ROS nodes (eqhrl-train in a process of its own, in a private ROS domain),
optionally with the user's env node."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from .run_pool import RunFailed
from .settings import Settings, env_node_command


def train_command(settings: Settings, algorithm: str, seed: int, directory: Path) -> list:
    """The eqhrl-train command of one run through the ROS nodes (the learner's settings it carries)."""
    command = [
        str(Path(sys.prefix) / 'bin' / 'eqhrl-train'),
        '--params',
        settings.params_path,
        '--output',
        str(directory),
        '--mode',
        algorithm,
        '--episodes',
        str(settings.episodes),
        '--seed',
        str(seed),
        '--max-steps',
        str(settings.max_episode_steps),
        '--overwrite',
    ]  # an unfinished run starts over
    if 'advising_budget' in settings.learner:
        command += ['--budget', str(settings.learner['advising_budget'])]
    if settings.learner.get('record'):
        command += ['--record']
    if settings.learner.get('prior'):
        command += ['--prior', *settings.learner['prior']]
    if settings.expert_backend == 'none':
        command += ['--expert-node', 'none']
    if settings.env_node:
        command += ['--env-node', 'none', '--discovery', 'localhost']
    return command


def run_through_ros(settings: Settings, algorithm: str, seed: int, directory: Path, progress, domain_id: int) -> None:
    command = train_command(settings, algorithm, seed, directory)
    env = dict(os.environ, OMP_NUM_THREADS='1')
    # A private domain per run, so that parallel runs never exchange messages.
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env_node = None
    with (directory / 'train.log').open('w') as log:
        if settings.env_node:
            with (directory / 'env_node.log').open('w') as env_log:
                env_node = subprocess.Popen(
                    env_node_command(settings.env_node, seed, settings.max_episode_steps),
                    stdout=env_log,
                    stderr=subprocess.STDOUT,
                    env=env,
                )
        try:
            process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
            seen = 0
            while process.poll() is None:
                time.sleep(1.0)
                seen = _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
                if env_node is not None and env_node.poll() is not None:
                    process.send_signal(signal.SIGINT)  # the env is gone: stop and save
                    process.wait()
                    raise RunFailed(
                        f'the env node exited ({env_node.returncode}) for {algorithm} seed {seed}; '
                        f'see {directory / "env_node.log"}'
                    )
            _report_new_rows(directory / 'episodes.csv', seen, algorithm, seed, progress)
        finally:
            if env_node is not None and env_node.poll() is None:
                env_node.send_signal(signal.SIGINT)
                try:
                    env_node.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    env_node.kill()
                    env_node.wait()
    if process.returncode != 0:
        raise RunFailed(f'eqhrl-train failed for {algorithm} seed {seed}; see {directory / "train.log"}')


def _report_new_rows(path: Path, seen: int, algorithm: str, seed: int, progress) -> int:
    if not path.exists():
        return seen
    with path.open(newline='') as f:
        rows = list(csv.DictReader(f))
    for row in rows[seen:]:
        progress.put((algorithm, seed, int(row['episode']), float(row['return'])))
    return len(rows)


def domain_ids(count: int) -> list:
    """A ROS domain per run, distinct among the runs of one experiment (at most 100 at a
    time), offset by this process's id so that two experiments on one machine rarely meet."""
    return [1 + (os.getpid() + index) % 100 for index in range(count)]
