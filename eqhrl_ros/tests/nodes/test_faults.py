"""Faults injected one by one: the learner keeps training, counts what happened, loses nothing."""

import csv
import gc
import io
import os
import re
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
import torch
from rclpy.clock import ClockType
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.serialization import serialize_message
from std_msgs.msg import Float32MultiArray, MultiArrayLayout

from eqhrl_interfaces.msg import AdviceRequest, EnvInfo
from eqhrl_interfaces.srv import Advise
from eqhrl_ros.core.data.signing import KeyFileError, Signer, new_key_file, read_key
from eqhrl_ros.core.envs.spec import EnvSpec
from eqhrl_ros.nodes import advise_msgs, env_info, messages
from eqhrl_ros.nodes.double_integrator_env_node import DoubleIntegratorEnv
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.keyboard_teleop_node import KeyboardTeleop
from eqhrl_ros.nodes.learner_node import OBSERVATION_QOS, LearnerNode

from process_helpers import BIN, episodes_in_csv, learner_args, start, stop, wait_for
from ros_helpers import Probe, StubExpert, observation_publisher, params, run_learner, small_learner_params


@pytest.mark.parametrize(
    'answer,kind', [([0.5, 0.5], 'wrong_size'), ([float('nan')], 'non_finite'), ([7.0], 'out_of_bounds')]
)
def test_bad_advice_is_counted_by_kind_and_never_used(harness, ros_context, tmp_path, monkeypatch, answer, kind):
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append((logger.name, line)))
    expert = StubExpert(ros_context, answer)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='qasac')
    finally:
        expert.close()
    # Said, with what was wrong (before: only the episode line's count by kind, so whoever wrote the
    # expert could not tell an action of 0.5 from one outside the bounds).
    words = {'wrong_size': '2 values where the env takes 1', 'non_finite': '[nan] is not finite'}
    words['out_of_bounds'] = '[7.] is outside the bounds [-2.] … [2.]'
    said = f"advice from 'stub' refused ({kind}): its action {words[kind]}"
    assert any(name == 'learner' and line.startswith(said) for name, line in warned), warned
    totals = learner.learner.advice_total
    # Each request is refused as its kind; a rare one times out instead (the stub answers from a thread
    # of this busy process, within advice_timeout_s 0.3 s: once in a cold CI rehearsal, 1 of 26).
    assert totals.asked > 0 and totals.failed[kind] > totals.failed['timeout']
    assert totals.failed[kind] + totals.failed['timeout'] == totals.asked and totals.given == 0
    assert len(learner.learner.advice_replay) == 0


HOSTILE_REASON = '\x1b[2J\x1b]0;owned\x07' + 'why ' * 50_000


@pytest.mark.parametrize(
    'answer,fields',
    [
        ([0.5], dict(human=True, response_time_s=float('nan'))),
        ('decline', dict(human=True, response_time_s=1e6, reason=HOSTILE_REASON)),
    ],
)
def test_an_experts_word_on_a_persons_time_and_reason_is_checked_by_meaning(
    harness, ros_context, tmp_path, monkeypatch, answer, fields
):
    """From outside, an expert of one's own (Advise.srv) said a person took NaN s or 10^6 s and
    declined with 200 KB of escape sequences: the learner counted 10^6 person seconds for a request it
    waited 0.3 s on, relayed the NaN on learner/advice_request (where the person's page drops a
    message that holds one, so the request stayed open on the screen) and the reason whole."""
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append((logger.name, line)))
    watch = harness.add(rclpy.create_node('request_watch', context=ros_context))
    ended = []
    watch.create_subscription(
        AdviceRequest, 'learner/advice_request', lambda m: m.outcome != AdviceRequest.PENDING and ended.append(m), 100
    )
    expert = StubExpert(ros_context, answer, **fields)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='random', random_ask_rate=0.3)
    finally:
        expert.close()
    assert harness.spin_until(lambda: len(ended) >= learner.learner.advice_total.asked > 0), (len(ended),)
    waited = 0.3 + 0.2  # advice_timeout_s, and the slack of a busy test process
    for message in ended:
        assert 0.0 <= message.response_time_s <= waited, message
        assert len(message.detail) <= 200 and message.detail.isprintable(), message.detail[:300]
    totals = learner.learner.advice_total
    assert 0.0 <= totals.human_time_s <= waited * totals.asked, totals
    claim = 'nan' if answer != 'decline' else '1000000.0'
    said = f"'stub' says a person took {claim} s on a request the learner waited"
    assert any(name == 'learner' and said in line for name, line in warned), warned


def test_a_persons_window_let_pass_is_no_refused_action():
    """A person's timeout carries no action: it must not be said to be a refused (NaN) one."""
    from types import SimpleNamespace

    from eqhrl_ros.core.algorithm.advice_outcomes import Resolution
    from eqhrl_ros.core.data.advice import Advice
    from eqhrl_ros.nodes.advice_client import say_unused_answer

    lines = []
    logger = SimpleNamespace(info=lambda line, **kw: lines.append(line), warn=lambda line, **kw: lines.append(line))
    scaler = SimpleNamespace(low=np.array([-2.0], np.float32), high=np.array([2.0], np.float32))
    own = np.zeros(1, np.float32)
    say_unused_answer(logger, Resolution(own, False, 'failed', 'timeout'), Advice.no_answer(4.0, 'person'), scaler)
    assert lines == []
    refused = Advice(np.array([9.0], np.float32), '', 'person', True)
    say_unused_answer(logger, Resolution(own, False, 'failed', 'out_of_bounds'), refused, scaler)
    assert lines == [
        "advice from 'person' refused (out_of_bounds): its action [9.] is outside the bounds [-2.] … [2.] "
        '(env units, as Advise.action_low/high give them); the learner took its own action'
    ]


def test_a_request_for_the_wheel_with_no_person_in_the_graph_says_the_graph_may_lag():
    """From outside: `ros2 launch … expert:=teleop` warned 3 s after its start that 'no node publishes
    /person_command' while teleop_expert did; the graph had not shown it yet."""
    from types import SimpleNamespace

    from eqhrl_ros.nodes.start_wait import StartWait

    said = []
    node = SimpleNamespace(get_logger=lambda: SimpleNamespace(warn=lambda line, **kw: said.append(line)))
    wait = StartWait(node, None, None, None, None, None, None, None)
    wait.say_unasked('wheel', '/env_info', '/person_command', advise_served=False)
    assert said == [
        "the gates fired, and nobody can take the wheel: the graph shows no node publishing '/person_command' "
        "(the person's teleop_expert; at a start, nodes launched together find each other over seconds), so "
        "nothing was asked (counted as unavailable, no person's seconds)"
    ]


# The probe's observations come from no env node, so no env_info says the env's pace: the
# learner is told its protocol (else advice_protocol auto holds the first observation for
# AUTO_PACE_WAIT_S, test_any_env says how).
NO_ENV_INFO = dict(advice_protocol='answer')


def test_expert_that_crashes_and_comes_back(harness, ros_context, tmp_path):
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path, mode='qasac', advising_budget=1000, max_episodes=9, advice_timeout_s=0.2
            ),
        )
    )
    expert = StubExpert(ros_context)
    assert harness.spin_until(lambda: learner.learner.episode >= 2, timeout=60)
    expert.close()  # the expert dies mid-run
    given_before = learner.learner.advice_total.given
    assert given_before > 0
    assert harness.spin_until(lambda: learner.learner.episode >= 5, timeout=60)
    totals = learner.learner.advice_total
    missed = totals.failed['unavailable'] + totals.failed['timeout']
    assert missed > 0 and totals.given == given_before  # training went on alone
    expert = StubExpert(ros_context, name='stub_expert_again')  # and it comes back
    try:
        assert harness.spin_until(lambda: learner.done, timeout=60)
    finally:
        expert.close()
    assert learner.learner.advice_total.given > given_before
    assert learner.learner.episode == 9


def test_untrusted_expert_is_refused(harness, ros_context, tmp_path):
    expert = StubExpert(ros_context)  # answers as 'stub'
    try:
        learner, _ = run_learner(
            harness, ros_context, tmp_path, episodes=2, mode='qasac', accept_expert='/trusted_expert'
        )
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.failed['untrusted'] == totals.asked and totals.given == 0


def test_no_answer_is_taken_while_two_nodes_serve_advise(harness, ros_context, tmp_path, monkeypatch):
    """From outside: a stranger serving 'advise' beside the expert answered first as often as not,
    and its actions went into D and D_advising (the learner only warned). rclpy does not say which
    server an answer came from, so while two nodes serve, none is taken, as with two publishers."""
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append((logger.name, line)))
    experts = [StubExpert(ros_context, name='expert'), StubExpert(ros_context, [2.0], name='stranger')]
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='random', random_ask_rate=0.3)
    finally:
        for expert in experts:
            expert.close()
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.given == 0 and len(learner.learner.advice_replay) == 0, totals
    assert totals.failed['untrusted'] + totals.failed['timeout'] == totals.asked and totals.failed['untrusted'] > 0
    said = "ignored advice: 2 nodes serve '/advise' (/expert, /stranger), so an answer cannot be told from a stranger's"
    assert any(name == 'learner' and line.startswith(said) for name, line in warned), warned


def _signed_call(harness, client, seal, entropy=float('nan'), frames=()):
    """A Pendulum request, signed with ``seal`` (None: unsigned), and the expert's response."""
    request = advise_msgs.sign_request(
        Advise.Request(
            observation=[1.0, 0.0, 0.0],
            proposed_action=[0.0],
            action_low=[-2.0],
            action_high=[2.0],
            entropy=entropy,
            episode=1,
            step=2,
            frames=list(frames),
        ),  # fmt: skip
        seal,
    )
    future = client.call_async(request)
    assert harness.spin_until(future.done, timeout=10)
    return request, future.result()


def test_with_a_shared_key_the_expert_answers_only_requests_signed_with_it(harness, ros_context, tmp_path):
    """Anyone on the graph may call 'advise'. With key_file, the expert declines at once (unsigned
    itself) a request not signed with the key, or one it has already taken (anyone reads the
    requests, so a copy could be sent again), and signs each answer for its request. QASAC's entropy
    is NaN, whose bits must not break the signature on the way; a camera's frames are covered."""
    from sensor_msgs.msg import Image

    key = str(new_key_file(tmp_path / 'deployment.key'))
    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1', key_file=key)))
    caller = harness.add(rclpy.create_node('caller', context=ros_context))
    client = caller.create_client(Advise, 'advise')
    assert harness.spin_until(client.service_is_ready)
    seal = advise_msgs.request_seal(Signer(read_key(key)))
    _, unsigned = _signed_call(harness, client, None)
    assert not unsigned.advised and unsigned.reason == 'request refused: it is unsigned and this node has a key_file'
    assert len(unsigned.signature) == 0
    _, forged = _signed_call(harness, client, advise_msgs.request_seal(Signer(b'not the deployment key!!')))
    assert not forged.advised and 'not made with this key_file' in forged.reason
    frame = Image(height=2, width=2, encoding='mono8', step=2, data=[0, 1, 2, 3])
    request, answer = _signed_call(harness, client, seal, frames=[frame])
    assert answer.advised and len(answer.action) == 1 and advise_msgs.answer_refusal(answer, request, seal) == ''
    answer.action = [2.0]  # altered on the way
    assert 'not made with this key_file' in advise_msgs.answer_refusal(answer, request, seal)
    replayed = client.call_async(request)
    assert harness.spin_until(replayed.done, timeout=10)
    assert not replayed.result().advised and 'replay' in replayed.result().reason


def _keyed_learner_beside_a_stranger(harness, ros_context, tmp_path, monkeypatch, with_expert, **stranger):
    """A learner with a key_file asking at 30 % of 2 episodes' steps while a StubExpert (``stranger``)
    serves 'advise' unsigned, beside an expert with the key when ``with_expert``. Returns the
    learner, the stranger and the learner's warnings."""
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append((logger.name, line)))
    key = str(new_key_file(tmp_path / 'deployment.key'))
    if with_expert:
        harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1', key_file=key)))
    stranger = StubExpert(ros_context, name='stranger', **stranger)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='random', random_ask_rate=0.3,
                                 key_file=key)  # fmt: skip
    finally:
        stranger.close()
    return learner, stranger, [line for name, line in warned if name == 'learner']


def test_with_a_shared_key_the_learner_takes_no_unsigned_answer(harness, ros_context, tmp_path, monkeypatch):
    """A stranger serving 'advise' alone, while the real expert is away, was believed. With
    key_file, the learner signs its requests and takes only answers signed for them."""
    learner, stranger, warned = _keyed_learner_beside_a_stranger(
        harness, ros_context, tmp_path, monkeypatch, with_expert=False, expert_name='/stranger'
    )
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.given == 0 and len(learner.learner.advice_replay) == 0, totals
    assert totals.failed['untrusted'] + totals.failed['timeout'] == totals.asked and totals.failed['untrusted'] > 0
    assert all(stranger.signatures) and len(stranger.signatures) >= totals.failed['untrusted']
    assert "ignored advice from '/stranger': it is unsigned and this node has a key_file" in warned, warned


def test_with_a_shared_key_the_experts_answers_are_taken_beside_a_strangers(
    harness, ros_context, tmp_path, monkeypatch
):
    """Two nodes serve 'advise': without a key no answer is taken (see above); with key_file the
    signature tells the expert's answers from the stranger's, and they are taken."""
    learner, stranger, warned = _keyed_learner_beside_a_stranger(
        harness,
        ros_context,
        tmp_path,
        monkeypatch,
        with_expert=True,
        delay=0.2,  # answers after the expert
    )
    totals = learner.learner.advice_total
    assert stranger.signatures and totals.given > 0 and len(learner.learner.advice_replay) == totals.given, totals
    assert not any('nodes serve' in line for line in warned), warned


def test_an_expert_of_ones_own_written_as_the_readme_shows_answers_a_learner_with_the_key(
    harness, ros_context, tmp_path
):
    """The README's own expert (Security), run as written, with the deployment's key: the learner
    takes its answers, and a key file that cannot be one refuses it."""
    import re
    from pathlib import Path

    readme = (Path(__file__).parents[2] / 'README.md').read_text()
    section = readme.split('An expert of your own signs as', 1)[1]
    code = re.search(r'```python\n(.*?)```', section, re.S).group(1)
    scope: dict = {}
    exec(compile(code, 'README.md', 'exec'), scope)
    key = str(new_key_file(tmp_path / 'deployment.key'))
    harness.add(scope['MyExpert'](key, context=ros_context))
    learner, _ = run_learner(harness, ros_context, tmp_path / 'run', episodes=2, mode='random', random_ask_rate=0.3,
                             key_file=key)  # fmt: skip
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.given + totals.failed['timeout'] == totals.asked and totals.given > 0, totals
    advised = learner.learner.advice_replay
    assert set(advised.action[: len(advised)].flatten().tolist()) == {0.0}  # the README's action
    (tmp_path / 'short.key').write_text('secret\n')
    with pytest.raises(KeyFileError, match='at least 16'):
        scope['MyExpert'](str(tmp_path / 'short.key'), context=ros_context)


def test_a_node_says_when_other_users_may_read_its_key_file(ros_context, tmp_path, monkeypatch):
    """The README says to keep the key chmod 600; a node now says so when it is not."""
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append((logger.name, line)))
    key = new_key_file(tmp_path / 'deployment.key')
    os.chmod(key, 0o644)
    expert = ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1', key_file=str(key)))
    expert.destroy_node()
    assert ('expert', f'the key file {key} is readable by other users of this machine, who could sign as this '
            f'deployment: chmod 600 {key}') in warned, warned  # fmt: skip


def test_an_answer_that_cannot_be_read_ends_its_request_as_an_error(harness, ros_context, tmp_path, monkeypatch):
    """The request is taken off the client before its answer is read: an answer whose reading
    raised left the request open for ever, and a lock-step run waited on it. Now it ends as 'error'."""
    from eqhrl_ros.nodes import advice_client

    calls = []

    def unreadable(response, name):
        calls.append(name)
        raise UnicodeError('an answer no one could read')

    monkeypatch.setattr(advice_client.advise_msgs, 'advice_from_response', unreadable)
    expert = StubExpert(ros_context)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='random', random_ask_rate=0.3)
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert calls and totals.failed['error'] == len(calls) and totals.given == 0, totals


def test_env_that_dies_mid_episode_and_restarts(harness, ros_context, tmp_path):
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(tmp_path, mode='sac', max_episodes=4, stall_timeout_s=0.5),
        )
    )
    assert harness.spin_until(lambda: learner.learner.episode == 1 and learner.learner.episode_step >= 5)
    harness.executor.remove_node(env)  # the env dies in the middle of episode 1
    harness.nodes.remove(env)
    env.destroy_node()
    steps_at_death = learner.learner.total_steps
    stepped = learner.learner.episode_step
    assert harness.spin_until(lambda: learner.stalls == 1, timeout=10)
    # A silence alone drops nothing: the env may only be paused.
    assert learner.learner.episode == 1 and learner.learner.episode_step == stepped
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    assert harness.spin_until(lambda: learner.done, timeout=60)
    # The restarted env began a new episode (step 0): episode 1's unfinished part was
    # abandoned, its index reused; no transition was invented across the gap.
    assert learner.learner.total_steps == steps_at_death + 3 * 25
    assert episodes_in_csv(tmp_path / 'episodes.csv') == [0, 1, 2, 3]
    assert [s.length for s in learner.summaries] == [25] * 4
    assert not any(s.interrupted for s in learner.summaries)


def test_bad_observations_are_dropped_and_never_stored(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **NO_ENV_INFO))
    )
    publisher, probe = observation_publisher(harness)
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], 0.0, False, False, 0, 0))  # good
    publisher.publish(messages.build([('obs', [0.1, 0.2]), ('tail', [0, 0, 0, 0, 1])]))  # too short
    publisher.publish(messages.observation_msg([0.1, np.nan, 0.3], -1.0, False, False, 0, 1))
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], np.inf, False, False, 0, 1))
    # Finite, but no env's (max_abs_reward 1e4, max_abs_observation 1e6): one such reward in D made
    # every update that drew it non-finite, and spoiled the networks for good.
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], 3e38, False, False, 0, 1))
    publisher.publish(messages.observation_msg([0.1, 2e6, 0.3], -1.0, False, False, 0, 1))
    assert harness.spin_until(lambda: learner.dropped_messages == 5)
    publisher.publish(messages.observation_msg([0.2, 0.2, 0.3], -1.0, False, False, 0, 1))  # good again
    assert harness.spin_until(lambda: learner.learner.total_steps == 1)
    stored = learner.learner.replay
    assert len(stored) == 1 and torch.isfinite(stored.obs[:1]).all() and torch.isfinite(stored.reward[:1]).all()


def test_observation_error_names_topic_and_sizes():
    with pytest.raises(messages.MessageError, match=r"'observation': 7 values, expected 8"):
        messages.parse_observation(Float32MultiArray(data=[0.0] * 7), 3)


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
    with pytest.raises(messages.MessageError, match=r'7 values, expected 8'):
        messages.parse_observation(reader.values(short), 3)
    with pytest.raises(messages.MessageError, match='not a Float32MultiArray'):
        reader.values(b'\x00\x01\x00\x00\xff\xff\xff\xff')
    assert messages.parse_observation(reader.values(other), 3).step == 5  # still reads


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


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.slow
def test_learner_stopped_mid_episode_saves_and_resumes_without_gaps(tmp_path, sig):
    out = tmp_path / 'run'
    env = start('gym_env', '--ros-args', '-p', 'max_episode_steps:=20', log_dir=tmp_path)
    expert = start('expert', log_dir=tmp_path)
    try:
        learner = start('learner', *learner_args(out), log_dir=tmp_path)
        csv_path = out / 'episodes.csv'
        assert wait_for(lambda: csv_path.exists() and len(episodes_in_csv(csv_path)) >= 3, 90), stop(learner)
        time.sleep(0.13)  # somewhere inside the next episode
        log = stop(learner, sig)
        assert learner.returncode == 0, log
        done = episodes_in_csv(csv_path)
        probe = torch.load(out / 'checkpoint.pt', weights_only=True)
        assert probe['counters']['episode'] == len(done) == done[-1] + 1
        assert len(probe['gates']['d_queue']) > 0

        target = len(done) + 2
        resumed = start(
            'learner',
            *learner_args(
                out, ['-p', 'resume:=true', '-p', f'max_episodes:={target}', '-p', 'shutdown_when_done:=true']
            ),
            log_dir=tmp_path,
        )
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


@pytest.mark.parametrize(
    'line,key', [('    gama: 0.9', 'gama'), ('    batch_size: big', 'batch_size'), ('    tau: 2.0', 'tau')]
)
@pytest.mark.slow
def test_bad_params_file_is_refused_at_start_up_naming_the_key(tmp_path, line, key):
    params_file = tmp_path / 'bad.yaml'
    params_file.write_text(f'learner:\n  ros__parameters:\n    env_id: Pendulum-v1\n{line}\n')
    result = subprocess.run(
        [str(BIN / 'learner'), '--ros-args', '--params-file', str(params_file), '-p', f'output_dir:={tmp_path}'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1
    assert 'refused to start' in result.stderr and key in result.stderr, result.stderr[-2000:]
    assert 'Traceback' not in result.stderr


@pytest.mark.slow
def test_resume_from_a_corrupt_checkpoint_refuses_to_start(tmp_path):
    (tmp_path / 'checkpoint.pt').write_bytes(b'PK\x03\x04 this is not a zip file')
    result = subprocess.run(
        [str(BIN / 'learner'), '--ros-args', '-p', f'output_dir:={tmp_path}', '-p', 'resume:=true'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1 and 'not a readable eqhrl_ros.checkpoint' in result.stderr
    assert (tmp_path / 'checkpoint.pt').read_bytes().startswith(b'PK\x03\x04 this')  # left untouched


# ------------------------------------------------------------------ starved, flooded, relabelled


def rows_of(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_paused_env_continues_its_episode_and_no_row_is_corrupted(tmp_path):
    # SIGSTOP stands for an env that is paused or starved of CPU for longer than
    # stall_timeout_s. Its episode must go on when it comes back, never end up as a
    # fragment recorded as a whole episode.
    out = tmp_path / 'run'
    env = start('gym_env', '--ros-args', '-p', 'max_episode_steps:=40', log_dir=tmp_path)
    learner = start(
        'learner',
        *learner_args(out, ['-p', 'mode:=sac', '-p', 'stall_timeout_s:=0.3', '-p', 'checkpoint_every_episodes:=0']),
        log_dir=tmp_path,
    )
    csv_path = out / 'episodes.csv'
    try:
        assert wait_for(lambda: csv_path.exists() and len(rows_of(csv_path)) >= 1, 90), stop(learner)
        time.sleep(0.15)  # inside the next episode
        env.send_signal(signal.SIGSTOP)
        time.sleep(1.5)  # five stall timeouts
        env.send_signal(signal.SIGCONT)
        assert wait_for(lambda: len(rows_of(csv_path)) >= 4, 90)
    finally:
        env.send_signal(signal.SIGCONT)
        log = stop(learner)
        stop(env)
    assert 'no observation for' in log and 'observations are back after' in log, log[-3000:]
    rows = rows_of(csv_path)
    assert [int(r['episode']) for r in rows] == list(range(len(rows)))
    assert all(int(r['length']) == 40 and r['interrupted'] == '0' for r in rows), rows
    assert [int(r['total_steps']) for r in rows] == [40 * (i + 1) for i in range(len(rows))]


def publish_steps(harness, publisher, probe, learner, steps, obs_dim=3):
    """Publish observations (episode 0, the given steps) one at a time, as a lock-step env would."""
    for step in steps:
        done = step == steps[-1]
        before = learner.learner.total_steps + learner.learner.episode
        publisher.publish(messages.observation_msg([0.1, 0.2, 0.3 + step], -1.0, False, done, 0, step))
        harness.spin_until(
            lambda: learner.learner.total_steps + learner.learner.episode > before or (0, step) in probe.acted_on(),
            timeout=5,
        )


def test_a_lost_observation_marks_the_episode_interrupted(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, mode='sac'))
    )
    publisher, probe = observation_publisher(harness)
    publish_steps(harness, publisher, probe, learner, [0, 1, 2, 4, 5, 6])  # step 3 never arrives
    assert harness.spin_until(lambda: len(learner.summaries) == 1)
    summary = learner.summaries[0]
    assert summary.interrupted and not summary.success
    assert learner.observation_gaps == 1
    assert learner.learner.total_steps == 4  # no transition across the gap
    assert rows_of(tmp_path / 'episodes.csv')[0]['interrupted'] == '1'


def test_a_learner_that_joins_mid_episode_marks_it_interrupted(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, mode='sac'))
    )
    publisher, probe = observation_publisher(harness)
    publish_steps(harness, publisher, probe, learner, [7, 8, 9])
    assert harness.spin_until(lambda: len(learner.summaries) == 1)
    assert learner.summaries[0].interrupted and learner.summaries[0].length == 2


def test_advice_timeout_and_stall_warning_do_not_depend_on_ros_time(harness, ros_context, tmp_path):
    # use_sim_time with no /clock: ROS time stands still. The advice timeout must still fire.
    expert = StubExpert(ros_context, delay=1.0)
    try:
        harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
        learner = harness.add(
            LearnerNode(
                context=ros_context,
                parameter_overrides=small_learner_params(
                    tmp_path, mode='qasac', max_episodes=2, advice_timeout_s=0.2, use_sim_time=True
                ),
            )
        )
        assert harness.spin_until(lambda: learner.done, timeout=60)
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.failed['timeout'] == totals.asked and totals.given == 0


def test_no_node_waits_on_ros_time_so_a_stopped_clock_wedges_none(harness, ros_context, tmp_path):
    """use_sim_time with a /clock that stops or never starts (a simulator started paused): a timer
    on ROS time never fires. Before, the expert held the env's env_info for ever (its recheck was
    such a timer: a launch with use_sim_time:=true served no advice), keyboard_teleop sent no
    command, and the example env in real time never stepped."""
    sim = params(use_sim_time=True)
    expert = harness.add(ExpertNode(context=ros_context, parameter_overrides=sim))
    env = harness.add(rclpy.create_node('gym_env', context=ros_context))
    spec = EnvSpec('Pendulum-v1', 3, [-2.0], [2.0])
    env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(
        env_info.env_info_msg(spec, publisher='/gym_env')
    )
    # The env's own env_info, come before the graph shows the env publishing observations: held.
    assert harness.spin_until(lambda: expert.env_info.untrusted >= 1)
    env.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: expert.env_info.ready, timeout=5)  # rechecked, and taken
    read_end, write_end = os.pipe()
    try:
        others = [
            KeyboardTeleop(read_end, io.StringIO(), context=ros_context, parameter_overrides=sim),
            DoubleIntegratorEnv(
                context=ros_context, namespace='/rt', parameter_overrides=params(use_sim_time=True, realtime=True)
            ),
            DoubleIntegratorEnv(context=ros_context, namespace='/ls', parameter_overrides=sim),
            GymEnvNode(
                context=ros_context, namespace='/g', parameter_overrides=params(use_sim_time=True, realtime=True)
            ),
        ]
        for node in [expert, *map(harness.add, others)]:
            on_ros_time = [t.callback for t in node.timers if t.clock.clock_type == ClockType.ROS_TIME]
            assert not on_ros_time, (node.get_name(), on_ros_time)
    finally:
        os.close(read_end)
        os.close(write_end)


def test_a_relabelled_message_is_refused_not_read_by_position(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **NO_ENV_INFO))
    )
    publisher, probe = observation_publisher(harness)
    # Right size, but 'step' and 'episode' swapped, and another with obs of the wrong size.
    swapped = messages.build(
        [
            ('obs', [0.1, 0.2, 0.3]),
            ('reward', [0.0]),
            ('terminated', [0.0]),
            ('truncated', [0.0]),
            ('step', [0.0]),
            ('episode', [0.0]),
        ]
    )
    resized = messages.build(
        [
            ('obs', [0.1, 0.2]),
            ('reward', [0.0, 0.0]),
            ('terminated', [0.0]),
            ('truncated', [0.0]),
            ('episode', [0.0]),
            ('step', [0.0]),
        ]
    )
    publisher.publish(swapped)
    publisher.publish(resized)
    assert harness.spin_until(lambda: learner.dropped_messages == 2)
    harness.spin_until(lambda: False, timeout=0.3)
    assert probe.acted_on() == [] and learner.learner.total_steps == 0
    publisher.publish(Float32MultiArray(data=[0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0]))  # unlabelled: by position
    assert harness.spin_until(lambda: probe.acted_on() == [(0, 0)])


def test_check_layout_accepts_ours_and_unlabelled_only():
    ours = messages.observation_msg([0.1, 0.2, 0.3], 0.0, False, False, 0, 0)
    messages.check_layout(ours.layout, messages.observation_layouts(3), 'observation')
    messages.check_layout(Float32MultiArray().layout, messages.observation_layouts(3), 'observation')
    with pytest.raises(messages.MessageError, match=r'layout \[action:1\] is not'):
        messages.check_layout(messages.action_msg([0.5]).layout, messages.observation_layouts(3), 'observation')
    offset = messages.action_msg([0.5], 1, 2)
    offset.layout = MultiArrayLayout(dim=list(offset.layout.dim), data_offset=1)  # layouts are shared: copy
    with pytest.raises(messages.MessageError, match='data_offset 1'):
        messages.parse_action(offset, 1)


def test_expert_names_are_capped_and_sanitised(harness, ros_context, tmp_path, capfd):
    # An expert's name reaches the learner's log lines: it must not forge lines or flood them.
    forged = 'evil\n[INFO] [learner]: forged line ' + 'x' * 100_000
    expert = StubExpert(ros_context, expert_name=forged)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=1, mode='qasac', advising_budget=5)
    finally:
        expert.close()
    assert learner.learner.advice_total.given > 0
    log = capfd.readouterr().err
    assert 'answered by: evil?[INFO] [learner]: forged line xxx' in log
    assert not any(line.startswith('[INFO] [learner]: forged') for line in log.splitlines())
    assert max(len(line) for line in log.splitlines()) < 1000


def rss_mb() -> float:
    with open('/proc/self/status') as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith('VmRSS:'))


@pytest.mark.parametrize('harness', ['default'], indirect=True)
def test_a_flood_leaves_no_backlog_with_the_default_executor(harness, ros_context, tmp_path):
    # 100,000 invalid observations arrive while the learner is busy (not spinning). With a
    # wait-set executor only the subscription's QoS depth (100) waits, and memory stays
    # flat; an executor that queues one event per arriving message (the EventsExecutor,
    # +14 MB here) grows without bound under a flood.
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **NO_ENV_INFO))
    )
    publisher, probe = observation_publisher(harness)
    harness.spin_until(lambda: False, timeout=0.5)
    bad = serialize_message(Float32MultiArray(data=[0.5] * 3))
    gc.collect()
    before = rss_mb()
    for _ in range(100_000):
        publisher.publish(bad)
    time.sleep(0.5)  # let the middleware deliver
    gc.collect()
    grown = rss_mb() - before
    harness.spin_until(lambda: False, timeout=1.0)  # drain whatever waits
    assert grown < 5.0, f'{grown:.1f} MB held for 100,000 messages'
    assert 0 < learner.dropped_messages <= OBSERVATION_QOS.depth + 40
    publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], 0.0, False, False, 0, 0))
    assert harness.spin_until(lambda: (0, 0) in probe.acted_on(), timeout=2.0)  # back at once


def test_env_throttles_its_rejection_log(harness, ros_context, capfd):
    env = harness.add(GymEnvNode(context=ros_context))
    probe = Probe(harness)
    assert harness.spin_until(lambda: probe.action_pub.get_subscription_count() > 0)
    for _ in range(40):
        probe.action_pub.publish(messages.action_msg([0.1, 0.2]))
        harness.spin_until(lambda: False, timeout=0.01)
    assert harness.spin_until(lambda: env.rejected_actions == 40)
    logged = capfd.readouterr().err.count('rejected action')
    assert 1 <= logged <= 2


def test_a_resumed_run_that_reached_max_episodes_learns_and_writes_nothing_more(harness, ros_context, tmp_path, capfd):
    """Resuming a run that has reached max_episodes (the same params file again) adds not one
    episode more: the learner says so in one line and leaves the env alone; with
    shutdown_when_done (eqhrl-train --resume), it ends once spinning, not mid-construction.
    Resumed with another mode and critic_lr, it says so in a warning (before: not a word)."""
    first, _ = run_learner(harness, ros_context, tmp_path, episodes=2)
    steps = first.learner.total_steps
    first.close()
    harness.executor.remove_node(first)
    capfd.readouterr()
    overrides = small_learner_params(tmp_path, max_episodes=2, resume=True, mode='qasac', critic_lr=5e-4)
    resumed = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    said = capfd.readouterr().err
    assert "resumed with settings other than the run had at its save: mode 'qasac' (was 'eqsac'); critic_lr " in said
    assert 'advising_budget' not in said.split('resumed with settings')[1].splitlines()[0]
    harness.spin_until(lambda: False, timeout=2.0)  # the env re-sends its observation meanwhile
    assert resumed.done and resumed.learner.total_steps == steps and resumed.learner.episode == 2
    assert len(rows_of(tmp_path / 'episodes.csv')) == 2
    resumed.close()
    harness.executor.remove_node(resumed)
    overrides = small_learner_params(tmp_path, max_episodes=2, resume=True, shutdown_when_done=True)
    ending = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    assert ending.done and ros_context.ok()
    assert harness.spin_until(lambda: not ros_context.ok(), timeout=5.0)
    assert ending.learner.total_steps == steps and len(rows_of(tmp_path / 'episodes.csv')) == 2


def test_updates_spoiled_by_a_reward_too_large_for_float32_are_said(harness, ros_context, tmp_path, monkeypatch):
    """An env that sends a reward of 5e29 once (a glitch, a slip of units) to a learner whose
    max_abs_reward was raised that far (by default such a step is dropped: test above): every
    update whose batch draws it has a loss that is not finite, and the critic's weights whose
    squared gradients overflowed learn no more. Before, the learner applied them and said nothing."""
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append(line))
    overrides = small_learner_params(
        tmp_path, mode='sac', learning_starts=4, batch_size=8, max_abs_reward=1e30, **NO_ENV_INFO
    )
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    publisher, probe = observation_publisher(harness)
    for step in range(12):
        reward = 5e29 if step == 2 else -1.0
        publisher.publish(messages.observation_msg([0.1, 0.2, 0.3], reward, False, False, 0, step))
        assert harness.spin_until(lambda step=step: (0, step) in probe.acted_on())
    spoiled = learner.learner.updater.non_finite_updates
    assert spoiled > 0
    said = [re.match(r'(\d+) of (\d+) updates so far had a loss that is not finite', line) for line in warned]
    said = [found for found in said if found]
    assert said and 1 <= int(said[0][1]) <= spoiled <= learner.learner.updater.updates
    assert 'too large for float32' in said[0].string


@pytest.mark.parametrize(
    'tail,said',
    [
        ([0.0, 0.0, 0.0, 2.5], 'step 2.5 is not a whole number in [0, 16,777,216]'),
        ([0.0, 0.0, -1.0, 0.0], 'episode -1 is not a whole number'),
        ([0.0, 0.0, 0.0, 2.0**25], 'step 3.35544e+07 is not a whole number'),
        ([0.5, 0.0, 0.0, 3.0], 'terminated 0.5 is not 0 or 1'),
        ([0.0, 0.0, 0.0, 3.0, 2.0], 'success 2 is not 0 or 1'),
    ],
)
def test_an_observation_whose_step_or_flags_mean_nothing_is_refused_not_floored(tail, said):
    """Before, int() floored a step of 2.5 to 2 and a flag of 0.7 was read as true, unsaid."""
    values = np.array([0.1, 0.2, 0.3, -1.0, *tail], dtype=np.float32)  # obs[3], reward, then the tail
    with pytest.raises(messages.MessageError, match=re.escape(said)):
        messages.parse_observation(values, 3)
    assert messages.parse_observation(np.array([0.1, 0.2, 0.3, -1.0, 1.0, 0.0, 7.0, 3.0], np.float32), 3).step == 3
    with pytest.raises(messages.MessageError, match='step 1.5 is not a whole number'):
        messages.parse_action(np.array([0.5, 0.0, 1.5], np.float32), 1)
    assert messages.parse_action(np.array([0.5, 2.0, 9.0], np.float32), 1)[1] == (2, 9)
