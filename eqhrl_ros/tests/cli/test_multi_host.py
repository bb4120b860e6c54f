"""Actors and a trainer on two "hosts": Linux network namespaces joined by a veth pair, with
addresses inside them only. The trainer runs in one namespace; two actors, each with
its env and expert, in the other. Discovery goes over the link as across a real network (the
default SUBNET range, and ROS_STATIC_PEERS in case multicast does not pass).

Needs root (ip netns); skipped with that reason elsewhere. Traffic stays inside the namespaces
this test makes, and it deletes them."""

import csv
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from process_helpers import wait_for

pytestmark = pytest.mark.slow
BIN = Path(sys.executable).parent


def ip(*args, check=True):
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check, timeout=20)


@pytest.fixture
def two_hosts():
    """(trainer namespace, actors namespace, their addresses, the actors' end of the link)."""
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip('network namespaces need root and iproute2 (ip netns)')
    tag = f'{os.getpid() % 100000}'
    trainer_ns, actors_ns = f'eqhrl_t{tag}', f'eqhrl_a{tag}'
    trainer_if, actors_if = f'eqt{tag}', f'eqa{tag}'
    subnet = 10 + os.getpid() % 200
    addresses = (f'10.237.{subnet}.1', f'10.237.{subnet}.2')
    try:
        ip('netns', 'add', trainer_ns)
        ip('netns', 'add', actors_ns)
    except subprocess.CalledProcessError as error:
        pytest.skip(f'cannot make network namespaces here: {error.stderr.strip()}')
    try:
        ip('link', 'add', trainer_if, 'type', 'veth', 'peer', 'name', actors_if)
        for ns, dev, address in ((trainer_ns, trainer_if, addresses[0]), (actors_ns, actors_if, addresses[1])):
            ip('link', 'set', dev, 'netns', ns)
            ip('-n', ns, 'addr', 'add', f'{address}/24', 'dev', dev)
            ip('-n', ns, 'link', 'set', dev, 'up')
            ip('-n', ns, 'link', 'set', 'lo', 'up')
        yield trainer_ns, actors_ns, addresses, actors_if
    finally:
        for ns in (trainer_ns, actors_ns):
            ip('netns', 'del', ns, check=False)  # the veth pair goes with them


def start_in(ns, peer, log_dir, name, *args):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET', ROS_STATIC_PEERS=peer)
    log = open(log_dir / f'{name}.log', 'a')
    process = subprocess.Popen(
        ['ip', 'netns', 'exec', ns, str(BIN / args[0]), *args[1:]], stdout=log, stderr=subprocess.STDOUT, env=env
    )
    process.log = log
    return process


def text(process) -> str:
    # Through a handle of its own: seeking the process's handle would move their shared offset,
    # and the process's next lines would overwrite its first ones (it appends: mode 'a').
    with open(process.log.name, errors='replace') as log:
        return log.read()


def rows(path):
    if not path.exists():
        return []
    with path.open(newline='') as f:
        return list(csv.DictReader(f))


ALGORITHM = [
    '-p', 'env_id:=Pendulum-v1', '-p', 'hidden_sizes:=[16,16]', '-p', 'batch_size:=16', '-p', 'learning_starts:=100',
    '-p', 'advising_budget:=2', '-p', 'queue_length:=3',
]  # fmt: skip


def test_two_actors_on_another_host_feed_a_trainer_through_a_link_cut(two_hosts, tmp_path):
    trainer_ns, actors_ns, (trainer_ip, actors_ip), actors_if = two_hosts
    out = tmp_path / 'trainer'
    processes = [
        start_in(
            trainer_ns, actors_ip, tmp_path, 'trainer', 'trainer', '--ros-args', *ALGORITHM,
            '-p', f'output_dir:={out}', '-p', 'weights_every_updates:=5', '-p', 'checkpoint_every_episodes:=0',
            '-p', 'report_period_s:=2.0', '-p', 'actor_silence_s:=1.0', '-p', 'actors:=[/a0/actor, /a1/actor]',
        )
    ]  # fmt: skip
    for i in range(2):
        ns = f'/a{i}'
        processes += [
            start_in(
                actors_ns, trainer_ip, tmp_path, f'env{i}', 'gym_env', '--ros-args', '-r', f'__ns:={ns}',
                '-p', 'max_episode_steps:=30', '-p', f'seed:={i}',
            ),
            start_in(actors_ns, trainer_ip, tmp_path, f'expert{i}', 'expert', '--ros-args', '-r', f'__ns:={ns}',
                     '-p', 'env_id:=Pendulum-v1'),
            start_in(
                actors_ns, trainer_ip, tmp_path, f'actor{i}', 'actor', '--ros-args', '-r', f'__ns:={ns}', *ALGORITHM,
                '-p', 'batch_transitions:=10', '-p', 'flush_period_s:=0.2', '-p', f'seed:={i}',
            ),
        ]  # fmt: skip
    actors = [processes[3], processes[6]]
    try:

        def from_each(since=0):
            names = [r['actor'] for r in rows(out / 'episodes.csv')[since:]]
            return names.count('/a0/actor') >= 2 and names.count('/a1/actor') >= 2

        # Discovery across the link, transitions to the trainer, weights back to both actors.
        assert wait_for(from_each, 180), text(processes[0])[-3000:]
        assert wait_for(lambda: all('weights from trainer' in text(a) for a in actors), 120), text(actors[0])[-3000:]

        # The link is cut (the actors' host loses its interface) until the trainer has reported
        # both actors silent, then comes back.
        before = len(rows(out / 'episodes.csv'))
        warned = text(processes[0]).count('has sent nothing for')
        ip('-n', actors_ns, 'link', 'set', actors_if, 'down')
        silent = lambda: text(processes[0]).count('has sent nothing for') >= warned + 2  # noqa: E731
        assert wait_for(silent, 60), text(processes[0])[-3000:]
        ip('-n', actors_ns, 'link', 'set', actors_if, 'up')
        assert wait_for(lambda: from_each(before), 180), text(processes[0])[-3000:]
        episodes = [int(r['episode']) for r in rows(out / 'episodes.csv')]
        assert episodes == list(range(len(episodes)))  # one record, indexed over both actors
        assert all(p.poll() is None for p in processes), [p.args for p in processes if p.poll() is not None]
        # Nothing lost to the cut: every episode each actor finished is in the record exactly once
        # (batches published into the dead link are asked for again and sent again).
        envs = [processes[1], processes[4]]
        for process in envs:  # the robots stop: no more episodes, and no later batch shows a gap
            process.send_signal(signal.SIGINT)
        for process in envs:
            process.wait(timeout=30)
        finished = {f'/a{i}/actor': text(a).count(f'] [a{i}.actor]: episode ') for i, a in enumerate(actors)}

        def recorded():
            names = [r['actor'] for r in rows(out / 'episodes.csv')]
            return {name: names.count(name) for name in finished}

        assert wait_for(lambda: recorded() == finished, 60), (recorded(), finished, text(processes[0])[-3000:])
    finally:
        for process in processes:
            if process.poll() is None:
                process.terminate()
        for process in processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    rates = [line for line in text(processes[0]).splitlines() if 'transitions from' in line and 'refused' in line]
    assert rates, text(processes[0])[-3000:]
    print(rates[-1])  # what a link cut of 3 s cost: batches sent again, none lost
    assert ', 0 refused,' in rates[-1]  # nothing the actors sent was refused
