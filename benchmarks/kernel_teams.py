"""The compiled update at one thread, quiet and beside a busy process, by its kernels' team size.

    .venv/bin/python benchmarks/kernel_teams.py [--env Pendulum-v1] [--mode sac] [--seconds 4] [--rounds 2]

When the machine is crowded, core/algorithm/cpu_threads.py drops torch to one thread. A compiled
program's fused kernels keep the OpenMP team size they were built for (inductor's cpp.threads),
so compiled_update.py gives a learner a second program built for one thread
(CompiledUpdate.program). This measures why, in fresh processes taking turns: the update that
compile_update: true runs (Table 1's sizes, batch 256), its kernels built for --threads or for
one, called at one thread, updates per second quiet and with one busy-loop process beside it.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

MEASURE = r"""
import sys, time
sys.path.insert(0, 'benchmarks')
import torch
from eqhrl_ros.core.algorithm import compiled_update, cpu_threads
from profile_update import compiled_update as compiled_program

env_id, mode, team, threads, seconds = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
cpu_threads.fix(threads)
compile = torch.compile
def with_team(function, **kw):  # the learner's compile, its kernels built for `team` threads
    return compile(function, **{**kw, 'options': {**kw['options'], 'cpp.threads': team}})
compiled_update.torch.compile = with_team
function, arguments = compiled_program(env_id, mode, 1000)
torch.set_num_threads(1)  # what the governor does on a crowded machine
for _ in range(10):
    function(*arguments)
n, start = 0, time.perf_counter()
while time.perf_counter() - start < seconds:
    function(*arguments)
    n += 1
print(n / (time.perf_counter() - start))
"""


def measure(args, team: int) -> float:
    command = [sys.executable, '-c', MEASURE, args.env, args.mode, str(team), str(args.threads), str(args.seconds)]
    return float(subprocess.run(command, check=True, capture_output=True, text=True).stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--mode', default='sac')
    parser.add_argument('--threads', type=int, default=2, help='the most threads (the program built for them)')
    parser.add_argument('--seconds', type=float, default=4.0)
    parser.add_argument('--rounds', type=int, default=2)
    args = parser.parse_args()
    teams = (args.threads, 1)
    quiet: dict = {team: [] for team in teams}
    busy: dict = {team: [] for team in teams}
    for round_index in range(args.rounds):
        order = teams if round_index % 2 == 0 else teams[::-1]
        for team in order:
            quiet[team].append(measure(args, team))
        hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        try:
            time.sleep(0.5)
            for team in order:
                busy[team].append(measure(args, team))
        finally:
            hog.kill()
            hog.wait()
    print(f'{args.env} {args.mode}, compiled update called at 1 thread; updates/s, median of {args.rounds} rounds')
    print('| kernels built for | quiet | beside a busy process |')
    print('|---|---|---|')
    for team in teams:
        print(
            f'| {team} thread{"s" if team > 1 else ""} | {statistics.median(quiet[team]):.1f} | '
            f'{statistics.median(busy[team]):.1f} |'
        )


if __name__ == '__main__':
    main()
