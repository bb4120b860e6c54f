"""Faults injected one by one: the learner keeps training, counts what happened, loses nothing."""

import csv
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from std_msgs.msg import Float32MultiArray

from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from ros_helpers import PARAMS_DIR, Probe, StubExpert, params, run_learner, small_learner_params

BIN = Path(sys.prefix) / 'bin'


def episodes_in_csv(path):
    with open(path, newline='') as f:
        return [int(row['episode']) for row in csv.DictReader(f)]


@pytest.mark.parametrize('answer,kind', [([0.5, 0.5], 'wrong_size'), ([float('nan')], 'non_finite'),
                                         ([7.0], 'out_of_bounds')])
def test_bad_advice_is_counted_by_kind_and_never_used(harness, ros_context, tmp_path, answer, kind):
    expert = StubExpert(ros_context, answer)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='qasac')
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.failed[kind] == totals.asked and totals.given == 0
    assert len(learner.learner.advice_replay) == 0


def test_expert_that_crashes_and_comes_back(harness, ros_context, tmp_path):
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(
        tmp_path, mode='qasac', advising_budget=1000, max_episodes=9, advice_timeout_s=0.2)))
    expert = StubExpert(ros_context)
    assert harness.spin_until(lambda: learner.learner.episode >= 2, timeout=60)
    expert.close()                                        # the expert dies mid-run
    given_before = learner.learner.advice_total.given
    assert given_before > 0
    assert harness.spin_until(lambda: learner.learner.episode >= 5, timeout=60)
    totals = learner.learner.advice_total
    missed = totals.failed['unavailable'] + totals.failed['timeout']
    assert missed > 0 and totals.given == given_before   # training went on alone
    expert = StubExpert(ros_context, name='stub_expert_again')    # and it comes back
    try:
        assert harness.spin_until(lambda: learner.done, timeout=60)
    finally:
        expert.close()
    assert learner.learner.advice_total.given > given_before
    assert learner.learner.episode == 9


def test_untrusted_expert_is_refused(harness, ros_context, tmp_path):
    expert = StubExpert(ros_context)   # answers as 'stub'
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='qasac',
                                 accept_expert='/trusted_expert')
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.failed['untrusted'] == totals.asked and totals.given == 0


def test_env_that_dies_mid_episode_and_restarts(harness, ros_context, tmp_path):
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(
        tmp_path, mode='sac', max_episodes=4, stall_timeout_s=0.5)))
    assert harness.spin_until(lambda: learner.learner.episode == 1 and learner.learner.episode_step >= 5)
    harness.executor.remove_node(env)          # the env dies in the middle of episode 1
    harness.nodes.remove(env)
    env.destroy_node()
    steps_at_death = learner.learner.total_steps
    assert harness.spin_until(lambda: learner.stalled_episodes == 1, timeout=10)
    assert learner.learner.episode == 1 and learner.learner.episode_step == 0
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    assert harness.spin_until(lambda: learner.done, timeout=60)
    # No transition was invented across the gap: 4 full episodes plus the steps before the death.
    assert learner.learner.total_steps == steps_at_death + 3 * 25
    assert episodes_in_csv(tmp_path / 'episodes.csv') == [0, 1, 2, 3]
    assert [s.length for s in learner.summaries] == [25] * 4


def test_bad_observations_are_dropped_and_never_stored(harness, ros_context, tmp_path):
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path)))
    probe = Probe(harness)
    publisher = probe.node.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: publisher.get_subscription_count() > 0)
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], 0.0, False, False, 0, 0))  # good
    publisher.publish(messages.build([('obs', [0.1, 0.2]), ('tail', [0, 0, 0, 0, 1])]))     # too short
    publisher.publish(messages.observation_msg([0.1, np.nan, 0.3], -1.0, False, False, 0, 1))
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], np.inf, False, False, 0, 1))
    assert harness.spin_until(lambda: learner.dropped_messages == 3)
    publisher.publish(messages.observation_msg([0.2, 0.2, 0.3], -1.0, False, False, 0, 1))  # good again
    assert harness.spin_until(lambda: learner.learner.total_steps == 1)
    stored = learner.learner.replay
    assert len(stored) == 1 and torch.isfinite(stored.obs[:1]).all() and torch.isfinite(stored.reward[:1]).all()


def test_observation_error_names_topic_and_sizes():
    with pytest.raises(messages.MessageError, match=r"'observation': 7 values, expected 8"):
        messages.parse_observation(messages.build([('x', [0.0] * 7)]), 3)


def test_serialized_reader_deserializes_once_per_layout(monkeypatch):
    from rclpy.serialization import serialize_message
    out = messages.observation_out(3)
    calls = []
    real = messages.deserialize_message
    monkeypatch.setattr(messages, 'deserialize_message', lambda *a: calls.append(1) or real(*a))
    reader = messages.SerializedReader()
    for step in range(4):
        values = reader.values(out.fill([0.1, 0.2, step], -1.0, False, False, 0, step))
        assert messages.parse_observation(values, 3).step == step
        assert messages.parse_observation(values, 3).obs[2] == step
    assert len(calls) == 1
    # Another layout is read in full, then becomes the fast one; a bad message is an error.
    other = serialize_message(Float32MultiArray(data=[0.0, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0, 5.0]))
    assert messages.parse_observation(reader.values(other), 3).step == 5
    assert messages.parse_observation(reader.values(other), 3).step == 5
    assert len(calls) == 2
    short = serialize_message(Float32MultiArray(data=[0.0] * 7))
    with pytest.raises(messages.MessageError, match=r"7 values, expected 8"):
        messages.parse_observation(reader.values(short), 3)
    with pytest.raises(messages.MessageError, match='not a Float32MultiArray'):
        reader.values(b'\x00\x01\x00\x00\xff\xff\xff\xff')
    assert messages.parse_observation(reader.values(other), 3).step == 5   # still reads


def test_outgoing_message_falls_back_to_the_message_if_bytes_are_not_as_expected(monkeypatch):
    from rclpy.serialization import serialize_message
    # A middleware whose encoding does not end with the values (here: 4 extra bytes).
    monkeypatch.setattr(messages, 'serialize_message', lambda msg: serialize_message(msg) + bytes(4))
    out = messages.action_out(2)
    assert not out.serialized
    msg = out.fill([0.5, -0.5], 3, 4)
    assert isinstance(msg, Float32MultiArray)
    assert messages.parse_action(msg, 2)[1] == (3, 4)
    assert messages.parse_fields(msg)['action'] == [0.5, -0.5]


# ------------------------------------------------------------------ processes

def start(executable, *args, log_dir):
    """A node as its own process; its output goes to a file (a full pipe would block it)."""
    log = open(log_dir / f'{executable}-{time.monotonic_ns()}.log', 'w+')
    process = subprocess.Popen([str(BIN / executable), *args], stdout=log, stderr=subprocess.STDOUT, text=True)
    process.log = log
    return process


def output(process) -> str:
    process.log.flush()
    process.log.seek(0)
    return process.log.read()


def stop(process, sig=signal.SIGINT, timeout=30) -> str:
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    text = output(process)
    process.log.close()
    return text


def wait_for(condition, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return False


def learner_args(out, extra=()):
    return ['--ros-args', '--params-file', str(PARAMS_DIR / 'demo.yaml'),
            '-p', f'output_dir:={out}', '-p', 'hidden_sizes:=[16,16]', '-p', 'learning_starts:=50',
            '-p', 'batch_size:=16', '-p', 'checkpoint_every_episodes:=1', *extra]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_learner_stopped_mid_episode_saves_and_resumes_without_gaps(tmp_path, sig):
    out = tmp_path / 'run'
    env = start('gym_env', '--ros-args', '-p', 'max_episode_steps:=20', log_dir=tmp_path)
    expert = start('expert', log_dir=tmp_path)
    try:
        learner = start('learner', *learner_args(out), log_dir=tmp_path)
        csv_path = out / 'episodes.csv'
        assert wait_for(lambda: csv_path.exists() and len(episodes_in_csv(csv_path)) >= 3, 90), stop(learner)
        time.sleep(0.13)                          # somewhere inside the next episode
        log = stop(learner, sig)
        assert learner.returncode == 0, log
        done = episodes_in_csv(csv_path)
        probe = torch.load(out / 'checkpoint.pt', weights_only=True)
        assert probe['counters']['episode'] == len(done) == done[-1] + 1
        assert len(probe['gates']['d_queue']) > 0

        target = len(done) + 2
        resumed = start('learner', *learner_args(out, ['-p', 'resume:=true', '-p', f'max_episodes:={target}',
                                                       '-p', 'shutdown_when_done:=true']), log_dir=tmp_path)
        try:
            resumed.wait(timeout=120)
        finally:
            log = stop(resumed)
        assert resumed.returncode == 0, log
        assert f'resumed from {out / "checkpoint.pt"} at episode {len(done)}' in log
        assert episodes_in_csv(csv_path) == list(range(target))
    finally:
        stop(env)
        stop(expert)


@pytest.mark.parametrize('line,key', [('    gama: 0.9', 'gama'), ('    batch_size: big', 'batch_size'),
                                      ('    tau: 2.0', 'tau')])
def test_bad_params_file_is_refused_at_start_up_naming_the_key(tmp_path, line, key):
    params_file = tmp_path / 'bad.yaml'
    params_file.write_text(f'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n{line}\n')
    result = subprocess.run([str(BIN / 'learner'), '--ros-args', '--params-file', str(params_file),
                             '-p', f'output_dir:={tmp_path}'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'refused to start' in result.stderr and key in result.stderr, result.stderr[-2000:]
    assert 'Traceback' not in result.stderr


def test_resume_from_a_corrupt_checkpoint_refuses_to_start(tmp_path):
    (tmp_path / 'checkpoint.pt').write_bytes(b'PK\x03\x04 this is not a zip file')
    result = subprocess.run([str(BIN / 'learner'), '--ros-args', '-p', f'output_dir:={tmp_path}',
                             '-p', 'resume:=true'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and 'not a readable eqhrl_ros.checkpoint' in result.stderr
    assert (tmp_path / 'checkpoint.pt').read_bytes().startswith(b'PK\x03\x04 this')   # left untouched
