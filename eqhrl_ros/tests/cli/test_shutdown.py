"""Executables as a user runs them: --help, Ctrl-C (twice), SIGTERM, failed saves, two runs at once."""

import os
import resource
import signal
import subprocess
import time

import pytest
import torch

from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode

from process_helpers import BIN, fail_writes, learner_args, output, read_rows, start, stop, wait_for
from ros_helpers import params, small_learner_params

EXECUTABLES = (
    'gym_env',
    'learner',
    'actor',
    'trainer',
    'expert',
    'teleop_expert',
    'keyboard_teleop',
    'eqhrl-train',
    'eqhrl-demo',
    'eqhrl-experiment',
    'eqhrl-report',
)


@pytest.mark.parametrize('executable', EXECUTABLES)
def test_help_prints_usage_starts_nothing_and_loads_no_torch(executable, tmp_path):
    env = dict(os.environ, PYTHONPROFILEIMPORTTIME='1')
    result = subprocess.run(
        [str(BIN / executable), '--help'], capture_output=True, text=True, timeout=60, cwd=tmp_path, env=env
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith('usage:'), result.stdout[:500]
    imported = [line.rsplit('|', 1)[-1].strip() for line in result.stderr.splitlines() if 'import time:' in line]
    assert 'torch' not in imported and 'gymnasium' not in imported
    assert list(tmp_path.iterdir()) == []  # no runs/ folder, nothing written


def test_a_node_refuses_arguments_that_are_not_ros_arguments(tmp_path):
    result = subprocess.run(
        [str(BIN / 'learner'), '--output', 'x'], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert result.returncode == 2 and 'unrecognized argument(s): --output x' in result.stderr
    assert list(tmp_path.iterdir()) == []


def clean(log):
    return 'Traceback' not in log and 'FATAL' not in log and 'KeyboardInterrupt' not in log


@pytest.mark.parametrize('twice', [False, True], ids=['once', 'twice'])
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.slow
def test_every_node_exits_0_and_quietly_on_a_signal_and_a_second_one(tmp_path, sig, twice):
    # A Ctrl-C in a terminal reaches every process of the group, then `ros2 launch` sends
    # SIGINT again (and SIGTERM after a while): a second signal lands during shutdown.
    out = tmp_path / 'run'
    nodes = {
        'gym_env': start('gym_env', '--ros-args', '-p', 'max_episode_steps:=20', log_dir=tmp_path),
        'expert': start('expert', log_dir=tmp_path),
        'teleop_expert': start('teleop_expert', log_dir=tmp_path),
        # The example env in a namespace of its own, beside the graph under test.
        'double_integrator_env': start('double_integrator_env', '--ros-args', '-r', '__ns:=/example', log_dir=tmp_path),
        'learner': start(
            'learner',
            *learner_args(
                out, ['-p', 'mode:=qasac', '-p', 'advising_budget:=1000', '-p', 'checkpoint_every_episodes:=0']
            ),
            log_dir=tmp_path,
        ),
    }
    try:
        assert wait_for(lambda: (out / 'episodes.csv').exists() and len(read_rows(out / 'episodes.csv')) >= 2, 90), (
            stop(nodes['learner'])
        )
    finally:
        for process in nodes.values():
            process.send_signal(sig)
        if twice:
            time.sleep(0.05)
            for process in nodes.values():
                if process.poll() is None:
                    process.send_signal(sig)
        logs = {name: stop(process) for name, process in nodes.items()}
    for name, process in nodes.items():
        assert process.returncode == 0, (name, logs[name][-3000:])
        assert clean(logs[name]), (name, logs[name][-3000:])
    state = torch.load(out / 'checkpoint.pt', weights_only=True)
    assert state['counters']['episode'] >= 2
    # Its last line says what was saved, where (before: nothing after the last episode's line).
    saved = f'saved in {out}: {state["counters"]["episode"]} episodes, '
    assert saved in logs['learner'].strip().splitlines()[-1], logs['learner'][-1000:]


def test_a_node_whose_starter_dies_stops_as_at_ctrl_c(tmp_path):
    """From outside: `kill <pid of ros2 launch>` (SIGTERM) ended the launch and left its nodes
    running (launch's own: 'using SIGTERM can result in orphaned processes'); so did a kill -9 of
    it or of `ros2 run`. The orphaned learner went on acting beside the next launch's. Now a node
    stops when the process that started it dies, as at Ctrl-C."""
    import sys

    log = tmp_path / 'node.log'
    starter_code = (
        'import subprocess, sys\n'
        'with open(sys.argv[1], "w") as log:\n'
        '    node = subprocess.Popen(sys.argv[2:], stdout=log, stderr=subprocess.STDOUT)\n'
        '    print(node.pid, flush=True)\n'
        '    node.wait()\n'
    )
    command = [str(BIN / 'double_integrator_env'), '--ros-args', '-r', '__ns:=/orphan']
    starter = subprocess.Popen(
        [sys.executable, '-c', starter_code, str(log), *command], stdout=subprocess.PIPE, text=True
    )
    node = int(starter.stdout.readline())
    try:
        assert wait_for(lambda: 'lock-step' in log.read_text(), 60), log.read_text()
        starter.kill()  # as a kill -9 of ros2 run, or launch's own end at SIGTERM
        starter.wait()
        assert wait_for(lambda: not os.path.exists(f'/proc/{node}') or ' Z ' in open(f'/proc/{node}/stat').read(), 20)
    finally:
        if os.path.exists(f'/proc/{node}'):
            os.kill(node, signal.SIGKILL)
    assert clean(log.read_text()), log.read_text()[-2000:]


@pytest.mark.slow
def test_a_signal_during_updates_never_saves_half_an_update(tmp_path):
    # Updates take most of each step here, so the signal lands inside one. Each update
    # steps the critics, the actor and the temperature once (SAC): the saved optimisers
    # must all have taken exactly `updates` steps.
    out = tmp_path / 'run'
    env = start('gym_env', '--ros-args', '-p', 'max_episode_steps:=50', log_dir=tmp_path)
    learner = start(
        'learner',
        *learner_args(
            out,
            [
                '-p',
                'mode:=sac',
                '-p',
                'hidden_sizes:=[128,128]',
                '-p',
                'batch_size:=128',
                '-p',
                'torch_threads:=1',
                '-p',
                'checkpoint_every_episodes:=0',
            ],
        ),
        log_dir=tmp_path,
    )
    try:
        assert wait_for(lambda: (out / 'episodes.csv').exists() and len(read_rows(out / 'episodes.csv')) >= 2, 90), (
            stop(learner)
        )
        time.sleep(0.37)
    finally:
        log = stop(learner)
        stop(env)
    assert learner.returncode == 0 and clean(log), log[-3000:]
    state = torch.load(out / 'checkpoint.pt', weights_only=True)
    updates = state['counters']['updates']
    assert updates > 0
    for name in ('actor_optimizer', 'critic_optimizer', 'alpha_optimizer'):
        steps = {float(s['step']) for s in state[name]['state'].values()}
        assert steps == {float(updates)}, (name, steps, updates)


def limit_file_size(limit):
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.slow
def test_a_save_that_fails_at_exit_says_so_and_exits_non_zero(tmp_path):
    # Files may grow to 6 KB: the CSV fits, a checkpoint does not (a real EFBIG from the
    # OS, as a full disk gives ENOSPC). Periodic saves fail with one line each and training
    # goes on; the save at exit fails and the exit code says so.
    out = tmp_path / 'run'
    env = start('gym_env', '--ros-args', '-p', 'max_episode_steps:=10', log_dir=tmp_path)
    # No expert here: the learner acts at once rather than wait expert_wait_s for one.
    args = learner_args(out, ['-p', 'expert_wait_s:=0.0'])
    learner = start('learner', *args, log_dir=tmp_path, preexec_fn=limit_file_size(6_000))
    try:
        assert wait_for(lambda: (out / 'episodes.csv').exists() and len(read_rows(out / 'episodes.csv')) >= 4, 90), (
            stop(learner)
        )
    finally:
        log = stop(learner)
        stop(env)
    assert learner.returncode == 1, log[-3000:]
    assert log.count('checkpoint not saved at episode') >= 3
    assert 'File too large' in log and 'training goes on' in log
    assert 'learner: checkpoint not saved at exit' in log
    assert 'Traceback' not in log
    assert not (out / 'checkpoint.pt').exists() and not list(out.glob('.*.tmp'))


def test_a_periodic_save_that_fails_keeps_the_previous_checkpoint_and_tries_again(
    harness, ros_context, tmp_path, monkeypatch
):
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10)))
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, mode='sac', max_episodes=6))
    )
    assert harness.spin_until(lambda: learner.learner.episode >= 2, timeout=60)
    saved = (tmp_path / 'checkpoint.pt').read_bytes()
    with monkeypatch.context() as patch:
        fail_writes(patch, to=str(tmp_path))  # the disk is full: no save, no CSV row can be written
        assert harness.spin_until(lambda: learner.failed_saves >= 2, timeout=60)
        assert learner.record.unwritten_rows >= 2  # kept for later, not lost
    assert (tmp_path / 'checkpoint.pt').read_bytes() == saved and not list(tmp_path.glob('.*.tmp'))
    assert harness.spin_until(lambda: learner.done, timeout=60)
    assert torch.load(tmp_path / 'checkpoint.pt', weights_only=True)['counters']['episode'] == 6
    assert [int(r['episode']) for r in read_rows(tmp_path / 'episodes.csv')] == list(range(6))


@pytest.mark.slow
def test_eqhrl_train_refuses_a_folder_with_a_run_unless_told(tmp_path):
    out = tmp_path / 'run'
    command = [
        str(BIN / 'eqhrl-train'),
        '--params',
        'demo',
        '--episodes',
        '1',
        '--max-steps',
        '5',
        '--output',
        str(out),
    ]
    first = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr[-2000:]
    rows = (out / 'episodes.csv').read_text()
    second = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert second.returncode == 1 and 'holds a run' in second.stderr and 'Traceback' not in second.stderr
    assert (out / 'episodes.csv').read_text() == rows
    third = subprocess.run(command + ['--overwrite'], capture_output=True, text=True, timeout=120)
    assert third.returncode == 0, third.stderr[-2000:]


@pytest.mark.slow
def test_two_eqhrl_train_runs_on_one_machine_do_not_hear_each_other(tmp_path):
    runs = [tmp_path / 'a', tmp_path / 'b']
    processes = [
        subprocess.Popen(
            [
                str(BIN / 'eqhrl-train'),
                '--params',
                'demo',
                '--episodes',
                '4',
                '--max-steps',
                '60',
                '--output',
                str(out),
                '--seed',
                str(i),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for i, out in enumerate(runs)
    ]
    logs = [p.communicate(timeout=180)[0] for p in processes]
    for process, log, out in zip(processes, logs, runs):
        assert process.returncode == 0, log[-3000:]
        assert 'does not follow' not in log and 'abandoning' not in log and 'interrupted' not in log.lower()
        rows = read_rows(out / 'episodes.csv')
        assert [int(r['total_steps']) for r in rows] == [60, 120, 180, 240], log[-3000:]


@pytest.mark.slow
@pytest.mark.parametrize('executable', ['trainer', 'actor', 'learner'])
def test_ctrl_c_while_the_node_still_imports_ends_it_quietly(executable, tmp_path):
    """Before: a KeyboardInterrupt traceback and exit code -2 (torch was still importing)."""
    own = [] if executable == 'actor' else ['-p', f'output_dir:={tmp_path}']  # an actor writes no run folder
    own += ['-p', 'accept_any_actor:=true'] if executable == 'trainer' else []  # else it refuses to start
    process = subprocess.Popen(
        [str(BIN / executable), '--ros-args', '-p', 'env_id:=Pendulum-v1', *own],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
    )

    def importing_torch():  # the node's own imports have begun (not the interpreter's start)
        try:
            return 'libtorch' in open(f'/proc/{process.pid}/maps').read()
        except OSError:
            return False

    try:
        assert wait_for(importing_torch, 60)
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:  # a failed test leaves no node behind
            process.kill()
            process.communicate()
    assert process.returncode == 0, out[-2000:]
    assert clean(out), out[-2000:]


# A node whose process ends while compile_update compiles: a daemon thread inside torch's C++
# (as inductor is), holding the compile lock, as the learner in its first half minute.
COMPILING_NODE = """
import threading
import torch
from rclpy.node import Node
from eqhrl_ros.core.algorithm import compiled_update
from eqhrl_ros.nodes.spinning import run_node

torch.set_num_threads(1)
a = torch.randn(1500, 1500)


def compiler():
    with compiled_update._COMPILING:
        while True:
            torch.mm(a, a)


class Quick(Node):
    def __init__(self):
        super().__init__('quick')
        threading.Thread(target=compiler, daemon=True).start()
        self.create_timer(0.5, self.context.try_shutdown)


run_node(Quick, name='quick')
"""


def test_a_node_that_ends_while_a_compile_runs_exits_with_its_status_not_an_abort(tmp_path):
    """Ending a learner (Ctrl-C, max_episodes) while compile_update still compiled in its daemon
    thread: the interpreter's own exit stopped that thread inside C++ and aborted the process (exit
    134, 'terminate called without an active exception'; `ros2 launch` said the learner died)."""
    script = tmp_path / 'compiling_node.py'
    script.write_text(COMPILING_NODE)
    result = subprocess.run([str(BIN / 'python'), str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and 'terminate called' not in result.stderr, result.stderr[-2000:]


def test_a_node_that_saves_nothing_does_not_say_it_is_finishing_a_save(capfd):
    """The second signal's line (run_node: saves=True only for nodes with an exit action)."""
    import faulthandler

    from eqhrl_ros.nodes.spinning import StopSignals

    for saves, said in ((False, 'already stopping, exiting'), (True, 'finishing the save')):
        stops = StopSignals('gym_env', saves=saves)
        stops._on_signal(signal.SIGINT, None)
        stops._on_signal(signal.SIGINT, None)
        faulthandler.cancel_dump_traceback_later()
        err = capfd.readouterr().err
        assert said in err and (saves or 'save' not in err), err


def test_a_record_cut_by_kill_9_reads_up_to_its_last_chunk(tmp_path):
    """The record closes its chunk every second: what a kill -9 leaves (no index, no summary)
    reads up to its last whole chunk, episodes in order."""
    from eqhrl_ros.files.mcap_record import read_record

    out = tmp_path / 'run'
    args = ['--params', 'demo', '--episodes', '200', '--max-steps', '20', '--output', str(out), '--record']
    process = start('eqhrl-train', *args, log_dir=tmp_path)

    def episodes_recorded():
        path = out / 'record.mcap'
        return [m.message.episode for m in read_record(path).on('/learner/episode_stats')] if path.exists() else []

    try:
        # The live file reads too, up to its last whole chunk.
        assert wait_for(lambda: len(episodes_recorded()) >= 3, 120), output(process)
        before = episodes_recorded()
        process.send_signal(signal.SIGKILL)
        process.wait()
    finally:
        stop(process)
    contents = read_record(out / 'record.mcap')
    assert not contents.complete and 'cut short' in contents.problem
    after = [m.message.episode for m in contents.on('/learner/episode_stats')]
    assert after[: len(before)] == before == list(range(len(before)))
    assert len(contents.on('/learner/transitions')) >= len(before)
