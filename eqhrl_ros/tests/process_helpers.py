"""Nodes as their own processes, as a user starts them: start, watch, signal, read the log."""

import csv
import signal
import subprocess
import sys
import time
from pathlib import Path

from ros_helpers import PARAMS_DIR

BIN = Path(sys.prefix) / 'bin'


def episodes_in_csv(path):
    with open(path, newline='') as f:
        return [int(row['episode']) for row in csv.DictReader(f)]


def read_rows(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def start(executable, *args, log_dir, **popen):
    """A node as its own process; its output goes to a file (a full pipe would block it)."""
    log = open(log_dir / f'{executable}-{time.monotonic_ns()}.log', 'a')
    process = subprocess.Popen([str(BIN / executable), *args], stdout=log, stderr=subprocess.STDOUT, text=True, **popen)
    process.log = log
    return process


def output(process) -> str:
    # Through a handle of its own: seeking the process's handle would move their shared offset,
    # and the process's next lines would overwrite its first ones (it appends: mode 'a').
    with open(process.log.name, errors='replace') as log:
        return log.read()


def stop(process, sig=signal.SIGINT, timeout=30) -> str:
    """Signal, wait (kill after ``timeout``), return the log. Safe to call twice (a failing
    assertion's message may stop a process that a finally clause stops again)."""
    if getattr(process, 'final_output', None) is not None:
        return process.final_output
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    text = output(process)
    process.log.close()
    process.final_output = text
    return text


def wait_for(condition, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return False


def settled(measure, quiet_s, timeout):
    """``measure()`` once it has not changed for ``quiet_s`` seconds (or when ``timeout`` ends)."""
    deadline = time.monotonic() + timeout
    value, since = measure(), time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - since < quiet_s:
        time.sleep(0.1)
        now = measure()
        if now != value:
            value, since = now, time.monotonic()
    return value


def learner_args(out, extra=()):
    return [
        '--ros-args',
        '--params-file',
        str(PARAMS_DIR / 'demo.yaml'),
        '-p',
        f'output_dir:={out}',
        '-p',
        'hidden_sizes:=[16,16]',
        '-p',
        'learning_starts:=50',
        '-p',
        'batch_size:=16',
        '-p',
        'checkpoint_every_episodes:=1',
        *extra,
    ]


def fail_writes(monkeypatch, to: str, error=28) -> None:
    """Make every os.write to a file whose name contains ``to`` fail as a full disk does
    (ENOSPC), as the OS would say it: the seam is the OS call, not our code's internals."""
    import os

    real = os.write

    def write(fd, data):
        try:
            name = os.readlink(f'/proc/self/fd/{fd}')
        except OSError:
            name = ''
        if to in name:
            raise OSError(error, os.strerror(error))
        return real(fd, data)

    monkeypatch.setattr(os, 'write', write)
