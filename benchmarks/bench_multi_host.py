"""Actors and a trainer on separate hosts, over a real (simulated) network, with packet loss.

    make bench-multi-host     # as root: .venv/bin/python benchmarks/bench_multi_host.py [options]

Each host is a Linux network namespace; they are joined by a bridge in a switch namespace, with
addresses inside the namespaces only (nothing reaches the machine's own network). Packet loss:
an nftables rule at the ingress of each host's link drops that share of the frames it receives
(``numgen random mod 100 < loss``, before IP reassembles fragments; this kernel has no netem).
Discovery as across a real network: the SUBNET range, with ROS_STATIC_PEERS in case multicast
does not pass.

The trainer (Table 1's networks, 256x256: weights of about 0.8 MB) runs on one host; each actor
host runs a lock-step Pendulum gym_env, the heuristic expert and an actor. For each variant (the Fast DDS
profile ``default``, or ``lossy_link``: share/eqhrl_ros/config/fastdds_lossy_link.xml with
net.core.rmem_max/wmem_max raised to 4 MB as it asks; ``+float16``: weights_on_wire:=float16),
1 and 2 actor hosts, and each loss rate,
it runs --seconds and prints: transitions/s and updates/s at the trainer, weights sent and
applied per actor (the share delivered: an actor takes the latest version, so a version
replaced before it arrived whole counts as not delivered), the weights' latency p50/p99 from
publish to applied, and the bytes on the trainer's link (sent: per weights message; received:
per transition).

--cut: the fault run instead: actors on one or two hosts, 60 s of learning, a 30 s cut of their
links, 60 s more, then a kill -9 of the trainer and a restart with resume, and 120 s more; at
the end the envs stop, and every episode each actor finished is looked for in the trainer's
episodes.csv: lost and duplicated (target 0), and the actors' transitions sent per transition
stepped (what the resends cost; target under 1.2) with the resent batches the trainer already had.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / 'eqhrl_ros' / 'config' / 'fastdds_lossy_link.xml'
BUFFER = 4 * 1024 * 1024
ALGORITHM = ['-p', 'env_id:=Pendulum-v1', '-p', 'learning_starts:=500', '-p', 'torch_threads:=1']


def sh(*args, check=True):
    return subprocess.run(list(args), capture_output=True, text=True, check=check, timeout=30)


class Network:
    """A switch namespace with a bridge, and host namespaces each joined to it by a veth pair."""

    def __init__(self, hosts: list[str], loss: int):
        tag = os.getpid() % 10000
        self.switch = f'eqb_sw{tag}'
        self.hosts = {name: f'eqb_{name}{tag}' for name in hosts}
        self.links = {name: f'{name}{tag}' for name in hosts}
        self.addresses = {name: f'10.238.{tag % 200}.{i + 1}' for i, name in enumerate(hosts)}
        sh('ip', 'netns', 'add', self.switch)
        sh('ip', '-n', self.switch, 'link', 'add', 'br0', 'type', 'bridge')
        sh('ip', '-n', self.switch, 'link', 'set', 'br0', 'up')
        for name, ns in self.hosts.items():
            sh('ip', 'netns', 'add', ns)
            link, port = self.links[name], f's{self.links[name]}'
            sh('ip', 'link', 'add', link, 'type', 'veth', 'peer', 'name', port)
            sh('ip', 'link', 'set', link, 'netns', ns)
            sh('ip', 'link', 'set', port, 'netns', self.switch)
            sh('ip', '-n', self.switch, 'link', 'set', port, 'master', 'br0')
            sh('ip', '-n', self.switch, 'link', 'set', port, 'up')
            sh('ip', '-n', ns, 'addr', 'add', f'{self.addresses[name]}/24', 'dev', link)
            sh('ip', '-n', ns, 'link', 'set', link, 'up')
            sh('ip', '-n', ns, 'link', 'set', 'lo', 'up')
            if loss:
                # At the device's ingress, before IP reassembles fragments: each frame is lost
                # with the given chance, as on a real link (an input-hook rule would see whole
                # datagrams, and lose a 64 KB datagram no more often than a small one).
                rules = (
                    'add table netdev eqhrl_loss\n'
                    f'add chain netdev eqhrl_loss ingress {{ type filter hook ingress device "{link}" priority 0; }}\n'
                    f'add rule netdev eqhrl_loss ingress numgen random mod 100 < {loss} counter drop\n'
                )
                subprocess.run(['ip', 'netns', 'exec', ns, 'nft', '-f', '-'], input=rules, text=True, check=True)

    def raise_buffers(self) -> str:
        """net.core.rmem_max/wmem_max to 4 MB in every host (per namespace on recent kernels)."""
        results = []
        for ns in self.hosts.values():
            for key in ('net.core.rmem_max', 'net.core.wmem_max'):
                done = sh('ip', 'netns', 'exec', ns, 'sysctl', '-w', f'{key}={BUFFER}', check=False)
                results.append(done.returncode == 0)
        return 'raised' if all(results) else 'not raised (sysctl refused)'

    def peers(self, name: str) -> str:
        return ';'.join(a for other, a in self.addresses.items() if other != name)

    def bytes(self, name: str) -> tuple[int, int]:
        """(sent, received) bytes on the host's link."""
        out = sh('ip', '-n', self.hosts[name], '-j', '-s', 'link', 'show', 'dev', self.links[name]).stdout
        stats = json.loads(out)[0]['stats64']
        return stats['tx']['bytes'], stats['rx']['bytes']

    def cut(self, name: str, down: bool) -> None:
        sh('ip', '-n', self.hosts[name], 'link', 'set', self.links[name], 'down' if down else 'up')

    def close(self) -> None:
        for ns in [*self.hosts.values(), self.switch]:
            sh('ip', 'netns', 'del', ns, check=False)


class Node:
    def __init__(self, network: Network, host: str, log_dir: Path, name: str, args: list, profile: str):
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET', ROS_STATIC_PEERS=network.peers(host))
        env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
        if profile == 'lossy_link':
            env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(PROFILE)
        self.log = open(log_dir / f'{name}-{time.monotonic_ns()}.log', 'w+')
        self.process = subprocess.Popen(
            ['ip', 'netns', 'exec', network.hosts[host], str(BIN / args[0]), *args[1:]],
            stdout=self.log,
            stderr=subprocess.STDOUT,
            env=env,
        )

    def text(self) -> str:
        self.log.flush()
        self.log.seek(0)
        return self.log.read()

    def stop(self, sig=signal.SIGINT) -> str:
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.text()


def wait_for(condition, timeout) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)
    return False


def start_trainer(network, log_dir, out: Path, actors: list[str], profile: str, *extra) -> Node:
    args = ['trainer', '--ros-args', *ALGORITHM, '-p', f'output_dir:={out}', '-p', 'report_period_s:=2.0']
    args += ['-p', f'actors:=[{", ".join(actors)}]', *extra]
    return Node(network, 'trainer', log_dir, 'trainer', args, profile)


def start_actor_host(network, log_dir, host: str, profile: str) -> list[Node]:
    ns = ['--ros-args', '-r', f'__ns:=/{host}']
    seed = ['-p', f'seed:={int(host[1:])}']
    return [
        Node(network, host, log_dir, f'env_{host}', ['gym_env', *ns, '-p', 'max_episode_steps:=200', *seed], profile),
        Node(network, host, log_dir, f'expert_{host}', ['expert', *ns, '-p', 'env_id:=Pendulum-v1'], profile),
        Node(
            network,
            host,
            log_dir,
            f'actor_{host}',
            ['actor', *ns, *ALGORITHM, *seed, '-p', 'flush_period_s:=0.2', '-p', 'advising_budget:=0'],
            profile,
        ),
    ]


REPORT = re.compile(
    r'\[(\d+\.\d+)\] \[trainer\]: (\d+) transitions from \d+ actor\(s\) .*?, (\d+) updates '
    r'.*?weights v\d+ sent (\d+) times'
)
SENT = re.compile(r'(\d+) steps; sent \d+ batches \((\d+) transitions, (\d+) batches again\)')
TWICE = re.compile(r'(\d+) received twice')
APPLIED = re.compile(r'weights applied (\d+)(?: \(latency p50 ([\d.]+) ms, p99 ([\d.]+) ms\))?')


def reports(text: str) -> list[tuple[float, int, int, int]]:
    return [(float(t), int(n), int(u), int(w)) for t, n, u, w in REPORT.findall(text)]


def throughput_run(hosts: int, loss: int, profile: str, wire: str, seconds: float, log_dir: Path) -> dict:
    names = ['trainer', *[f'h{i}' for i in range(hosts)]]
    network = Network(names, loss)
    nodes = []
    try:
        buffers = network.raise_buffers() if profile == 'lossy_link' else 'default'
        actors = [f'/h{i}/actor' for i in range(hosts)]
        out = log_dir / f'out_{profile}_{wire}_{hosts}_{loss}'
        trainer = start_trainer(network, log_dir, out, actors, profile, '-p', f'weights_on_wire:={wire}')
        nodes.append(trainer)
        actor_nodes = []
        for name in names[1:]:
            host_nodes = start_actor_host(network, log_dir, name, profile)
            nodes += host_nodes
            actor_nodes.append(host_nodes[2])
        # Measured once updates run and every actor has taken weights.
        if not wait_for(
            lambda: (
                any(r[2] > 0 for r in reports(trainer.text()))
                and all('weights from trainer' in a.text() for a in actor_nodes)
            ),
            240,
        ):
            return {'error': 'no weights reached the actors in 240 s', 'trainer': trainer.text()[-1500:]}
        start = reports(trainer.text())[-1]
        bytes0 = network.bytes('trainer')
        time.sleep(seconds)
        end = reports(trainer.text())[-1]
        bytes1 = network.bytes('trainer')
        for node in nodes[1:]:
            node.stop()
        # Weights sent until the actors stopped: the trainer's next report says.
        lines = len(reports(trainer.text()))
        wait_for(lambda: len(reports(trainer.text())) > lines, 10)
        sent_total = reports(trainer.text())[-1][3]
        applied = []
        for actor in actor_nodes:
            match = APPLIED.findall(actor.text())
            applied.append(match[-1] if match else ('0', '', ''))
        elapsed = end[0] - start[0]
        transitions, updates, weights = end[1] - start[1], end[2] - start[2], end[3] - start[3]
        sent, received = bytes1[0] - bytes0[0], bytes1[1] - bytes0[1]
        wall = seconds
        return {
            'buffers': buffers,
            'transitions/s': transitions / elapsed,
            'updates/s': updates / elapsed,
            'weights sent': sent_total,
            'weights sent/s': weights / elapsed,
            'applied': [int(a[0]) for a in applied],
            'share delivered': [int(a[0]) / max(sent_total, 1) for a in applied],
            'latency p50 ms': [a[1] or '-' for a in applied],
            'latency p99 ms': [a[2] or '-' for a in applied],
            'MB/s sent': sent / wall / 1e6,
            'MB/s received': received / wall / 1e6,
            'bytes per weights message (sent / weights)': sent / max(weights * hosts, 1),
            'bytes per transition (received / transitions)': received / max(transitions, 1),
        }
    finally:
        for node in nodes:
            node.stop()
        network.close()


def cut_run(hosts: int, profile: str, wire: str, log_dir: Path, cut_s: float = 30.0) -> dict:
    names = ['trainer', *[f'h{i}' for i in range(hosts)]]
    network = Network(names, 0)
    nodes = []
    out = log_dir / f'cut_{profile}_{wire}_{hosts}'
    extra = ['-p', 'checkpoint_every_episodes:=5', '-p', 'save_replay:=false', '-p', f'weights_on_wire:={wire}']
    try:
        if profile == 'lossy_link':
            network.raise_buffers()
        actors = [f'/h{i}/actor' for i in range(hosts)]
        trainer = start_trainer(network, log_dir, out, actors, profile, *extra)
        nodes.append(trainer)
        envs, actor_nodes = [], []
        for name in names[1:]:
            host_nodes = start_actor_host(network, log_dir, name, profile)
            nodes += host_nodes
            envs.append(host_nodes[0])
            actor_nodes.append(host_nodes[2])
        if not wait_for(lambda: all('weights from trainer' in a.text() for a in actor_nodes), 240):
            return {'error': 'no weights reached the actors in 240 s'}
        time.sleep(60)
        for name in names[1:]:
            network.cut(name, True)
        time.sleep(cut_s)
        for name in names[1:]:
            network.cut(name, False)
        time.sleep(60)
        trainer.stop(signal.SIGKILL)
        time.sleep(5)
        restarted = start_trainer(network, log_dir, out, actors, profile, *extra, '-p', 'resume:=true')
        nodes.append(restarted)
        wait_for(lambda: 'resumed from' in restarted.text(), 120)
        time.sleep(120)
        for env in envs:
            env.stop()
        finished = {
            f'/{name}/actor': actor.text().count(f'] [{name}.actor]: episode ')
            for name, actor in zip(names[1:], actor_nodes)
        }

        def recorded():
            path = out / 'episodes.csv'
            if not path.exists():
                return {}
            with path.open(newline='') as f:
                actors_of_rows = [row['actor'] for row in csv.DictReader(f)]
            return {name: actors_of_rows.count(name) for name in finished}

        wait_for(lambda: recorded() == finished, 120)
        stored = recorded()
        for actor in actor_nodes:
            actor.stop()
        sent = [SENT.findall(actor.text()) for actor in actor_nodes]
        steps = sum(int(s[-1][0]) for s in sent if s)
        transitions = sum(int(s[-1][1]) for s in sent if s)
        return {
            'transitions sent / stepped': transitions / max(steps, 1),
            'batches sent again': sum(int(s[-1][2]) for s in sent if s),
            # Resent batches the trainer already had: what a resend wasted (go-back-N: tens of thousands).
            'received twice': sum(
                int(n) for n in TWICE.findall(trainer.text())[-1:] + TWICE.findall(restarted.text())[-1:]
            ),
            'finished': finished,
            'recorded': stored,
            'lost': sum(max(0, finished[a] - stored.get(a, 0)) for a in finished),
            'duplicated': sum(max(0, stored.get(a, 0) - finished[a]) for a in finished),
        }
    finally:
        for node in nodes:
            node.stop()
        network.close()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0, help='measured seconds per configuration')
    parser.add_argument('--hosts', type=int, nargs='+', default=[1, 2], help='actor hosts')
    parser.add_argument('--loss', type=int, nargs='+', default=[0, 5], help='packet loss, percent')
    parser.add_argument(
        '--variants',
        nargs='+',
        default=['default', 'lossy_link', 'lossy_link+float16'],
        choices=['default', 'lossy_link', 'default+float16', 'lossy_link+float16'],
        help='Fast DDS profile, and +float16 for weights_on_wire:=float16',
    )
    parser.add_argument('--cut', action='store_true', help='the fault run (30 s cut, trainer kill -9 + resume)')
    args = parser.parse_args(argv)
    # A SIGTERM ends the run through its finally clauses: its nodes stopped, its namespaces deleted.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if os.geteuid() != 0 or not shutil.which('nft'):
        print('needs root, iproute2 and nftables (make bench-multi-host installs nftables)', file=sys.stderr)
        return 2
    log_dir = Path(tempfile.mkdtemp(prefix='bench_multi_host_'))
    print(f'logs in {log_dir}', flush=True)
    failed = False
    for variant in args.variants:
        profile, _, wire = variant.partition('+')
        wire = wire or 'float32'
        for hosts in args.hosts:
            if args.cut:
                result = cut_run(hosts, profile, wire, log_dir)
                print(f'cut  {variant:18s} actor hosts {hosts}: {result}', flush=True)
                failed |= bool(result.get('lost') or result.get('duplicated') or 'error' in result)
                failed |= result.get('transitions sent / stepped', 0) >= 1.2
                continue
            for loss in args.loss:
                result = throughput_run(hosts, loss, profile, wire, args.seconds, log_dir)
                shown = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in result.items()}
                shown = {
                    k: ([round(x, 3) if isinstance(x, float) else x for x in v] if isinstance(v, list) else v)
                    for k, v in shown.items()
                }
                print(f'{variant:18s} actor hosts {hosts} loss {loss:2d} %: {shown}', flush=True)
                failed |= 'error' in result
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
