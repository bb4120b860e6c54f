"""record: true — one MCAP file per run holding what the learner sent and received, every advise
call (both sides, from service introspection), every gate decision and the stored transitions;
read back with mcap-ros2-support and, independently, with rosbags; and prior: a later run seeded
with an earlier run's advice."""

import io

import numpy as np
import pytest
import rclpy
from std_msgs.msg import Bool

from eqhrl_ros.files.mcap_record import McapRecord, RecordError, load_prior, read_record
from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode

from process_helpers import read_rows
from ros_helpers import params, small_learner_params

REQUEST_SENT, REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = range(4)


def recorded_run(harness, ros_context, out, episodes=4, images=False, on_start=None, **extra):
    env = params(max_episode_steps=25, publish_images=images, image_rate_hz=20.0)
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=env))
    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    overrides = small_learner_params(out, max_episodes=episodes, record=True, publish_gate_debug=False, **extra)
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    if on_start is not None:
        # The learner has heard the latched STOP (a fixed wait lost it under load: only the
        # release was in the record).
        assert harness.spin_until(lambda: learner.tracking.stopped_since is not None, timeout=30)
        on_start()
    assert harness.spin_until(lambda: learner.done, timeout=90)
    learner.close()
    return learner


def test_a_recorded_run_holds_every_request_answer_gate_and_transition(harness, ros_context, tmp_path):
    # The person's STOP, pressed and released before the run: both are in the record.
    person = harness.add(rclpy.create_node('person', context=ros_context))
    stop = person.create_publisher(Bool, messages.STOP_TOPIC, messages.STOP_QOS)
    stop.publish(Bool(data=True))
    learner = recorded_run(harness, ros_context, tmp_path, images=True, on_start=lambda: stop.publish(Bool(data=False)))
    rows = read_rows(tmp_path / 'episodes.csv')
    asked = sum(int(r['advice_asked']) for r in rows)
    given = sum(int(r['advice_given']) for r in rows)
    steps = sum(int(r['length']) for r in rows)
    assert asked > 0, 'the gates never fired: nothing to check'

    contents = read_record(tmp_path / 'record.mcap')
    assert contents.complete, contents.problem
    events = [m.message for m in contents.on('/advise/_service_event')]
    kinds = [e.info.event_type for e in events]
    # Both sides of every call: the learner's client and the expert's server.
    assert [kinds.count(k) for k in range(4)] == [asked] * 4
    sent = [e for e in events if e.info.event_type == REQUEST_SENT]
    answered = [e for e in events if e.info.event_type == RESPONSE_RECEIVED]
    assert [e.info.sequence_number for e in sent] == sorted(e.info.sequence_number for e in sent)  # in order
    assert [e.info.sequence_number for e in sent] == [e.info.sequence_number for e in answered]
    assert all(len(e.request[0].observation) == 3 and np.isfinite(e.request[0].discrepancy) for e in sent)
    assert all(e.response[0].advised and len(e.response[0].action) == 1 for e in answered)
    assert all(e.response[0].response_time_s >= 0 for e in answered)  # the reaction time, with the answer

    requests = [m.message for m in contents.on('/learner/advice_request')]
    assert [r.outcome for r in requests].count(1) == given  # AdviceRequest.GIVEN
    gates = [m.message for m in contents.on('/learner/gate_debug')]
    assert len(gates) == steps  # every decision, though publish_gate_debug is false
    assert sum(g.fire for g in gates) == asked
    assert len(contents.on('/observation')) >= steps and len(contents.on('/action')) >= steps
    stats = [m.message for m in contents.on('/learner/episode_stats')]
    assert [s.episode for s in stats] == [int(r['episode']) for r in rows]
    batches = [m.message for m in contents.on('/learner/transitions')]
    assert sum(len(b.rewards) for b in batches) == steps == learner.learner.total_steps
    assert sum(sum(b.advised) for b in batches) == given == len(learner.learner.advice_replay)

    assert [m.message.data for m in contents.on('/stop')] == [True, False]
    frames = contents.on('/gym_env/image/compressed')
    assert frames and all(f.message.format == 'jpeg' for f in frames)
    from PIL import Image

    assert Image.open(io.BytesIO(bytes(frames[-1].message.data))).size[0] > 0  # a JPEG that opens

    # An independent reader: rosbags sees the same topics and message counts, and decodes them all.
    from rosbags.highlevel import AnyReader

    counts = {}
    with AnyReader([tmp_path / 'record.mcap']) as reader:
        for connection, _, raw in reader.messages():
            typename = connection.msgtype
            if typename not in reader.typestore.fielddefs:  # rosbags names a service's event pkg/srv/msg/Name
                typename = typename.replace('/srv/', '/srv/msg/')
            reader.typestore.deserialize_cdr(raw, typename)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    ours = {}
    for message in contents.messages:
        ours[message.topic] = ours.get(message.topic, 0) + 1
    assert counts == ours


def test_a_run_seeded_with_an_earlier_runs_advice_starts_with_it(harness, ros_context, tmp_path):
    first = recorded_run(harness, ros_context, tmp_path / 'first', episodes=3)
    advised = len(first.learner.advice_replay)
    assert advised > 0
    prior = load_prior([tmp_path / 'first'], 3, [-2.0], [2.0])
    assert len(prior) == advised
    assert np.allclose(np.sort(prior.rewards), np.sort(first.learner.advice_replay.reward[:advised].numpy()))

    second = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(tmp_path / 'second', prior=[str(tmp_path / 'first')]),
        )
    )
    assert len(second.learner.advice_replay) == advised and len(second.learner.replay) == advised
    assert second.learner.total_steps == 0  # prior data, not steps of this run


def record_of_other_spaces(path) -> None:
    """One advised transition of a 2-D observation in [-1, 1] actions, into the MCAP file ``path``."""
    record = McapRecord(path)
    record.write_fields(
        '/learner/transitions',
        'eqhrl_interfaces/msg/TransitionBatch',
        {
            'observation_size': 2,
            'action_low': [-1.0],
            'action_high': [1.0],
            'observations': [0.0, 0.0],
            'actions': [0.5],
            'rewards': [1.0],
            'next_observations': [0.0, 1.0],
            'terminated': [False],
            'advised': [True],
        },
    )
    record.close()


def test_a_prior_from_other_spaces_is_refused_in_one_line(tmp_path):
    record_of_other_spaces(tmp_path / 'record.mcap')
    with pytest.raises(RecordError, match='observations of 2 .* this env has 3'):
        load_prior([tmp_path], 3, [-2.0], [2.0])
    with pytest.raises(RecordError, match=r'actions in \[\[-1.0\], \[1.0\]\]'):
        load_prior([tmp_path / 'record.mcap'], 2, [-2.0], [2.0])
    assert len(load_prior([tmp_path], 2, [-1.0], [1.0])) == 1
    with pytest.raises(RecordError, match='no such file'):
        load_prior([tmp_path / 'nothing'], 2, [-1.0], [1.0])
    (tmp_path / 'empty').mkdir()
    with pytest.raises(RecordError, match='no record'):
        load_prior([tmp_path / 'empty'], 2, [-1.0], [1.0])
    # Before: any file read as a record cut short before its first message, and seeded nothing.
    (tmp_path / 'episodes.csv').write_text('episode,return\n0,-1.0\n')
    with pytest.raises(RecordError, match='episodes.csv: not an MCAP file'):
        load_prior([tmp_path / 'episodes.csv'], 2, [-1.0], [1.0])
    cut = tmp_path / 'cut.mcap'  # a record cut short (kill -9) is still one: read up to its last chunk
    cut.write_bytes((tmp_path / 'record.mcap').read_bytes()[:-100])
    assert load_prior([cut], 2, [-1.0], [1.0]).cut_short == [cut]


def test_a_start_refused_for_its_prior_keeps_the_run_it_would_overwrite_and_notes_no_start(ros_context, tmp_path):
    """Before (2026-12-05) the folder's overwrite and its provenance entry came when it was opened,
    before the prior was read: the refused start had removed the old run and noted a start that
    never ran."""
    record_of_other_spaces(tmp_path / 'prior.mcap')
    run = tmp_path / 'run'
    run.mkdir()
    (run / 'episodes.csv').write_text('episode,return\n0,-1.0\n')
    (run / 'checkpoint.pt').write_bytes(b'the old run')
    overrides = small_learner_params(run, overwrite=True, prior=[str(tmp_path / 'prior.mcap')])
    with pytest.raises(ValueError, match='prior: .*observations of 2 .* this env has 3'):
        LearnerNode(context=ros_context, parameter_overrides=overrides)
    assert (run / 'checkpoint.pt').read_bytes() == b'the old run' and (run / 'episodes.csv').exists()
    assert not (run / 'provenance.yaml').exists()


def test_a_prior_holding_a_value_no_env_sends_is_refused_in_one_line(ros_context, tmp_path):
    """A record is a file, trusted no more than the env's topic: prior data went into D and
    D_advising whatever its rewards (3e38 too), where the env's are now bounded (max_abs_reward)."""
    record = McapRecord(tmp_path / 'prior.mcap')
    batch = {'observation_size': 3, 'action_low': [-2.0], 'action_high': [2.0], 'observations': [0.0] * 3,
             'actions': [0.5], 'rewards': [2e4], 'next_observations': [0.0] * 3, 'terminated': [False],
             'advised': [True]}  # fmt: skip
    record.write_fields('/learner/transitions', 'eqhrl_interfaces/msg/TransitionBatch', batch)
    record.close()
    overrides = small_learner_params(tmp_path / 'run', prior=[str(tmp_path / 'prior.mcap')])
    with pytest.raises(
        ValueError, match=r'prior: .*prior.mcap: a reward of magnitude 2e\+04 is beyond max_abs_reward 10000'
    ):
        LearnerNode(context=ros_context, parameter_overrides=overrides)
    overrides = small_learner_params(tmp_path / 'run2', prior=[str(tmp_path / 'prior.mcap')], max_abs_reward=1e5)
    node = LearnerNode(context=ros_context, parameter_overrides=overrides)  # raised past it: taken, as asked
    assert len(node.learner.advice_replay) == 1
    node.destroy_node()


def test_a_record_cut_short_reads_up_to_its_last_chunk(tmp_path):
    """What a kill -9 leaves: no index and no summary, the last chunk maybe half written."""
    path = tmp_path / 'record.mcap'
    record = McapRecord(path, flush_period_s=0.0)  # a chunk per message
    for i in range(20):
        record.write_fields('/stop', 'std_msgs/msg/Bool', {'data': bool(i % 2)})
    record._file.flush()
    whole = path.read_bytes()
    cut = tmp_path / 'cut.mcap'
    for end in (len(whole) - 7, len(whole) - 60):  # into the last chunk's index, into the chunk
        cut.write_bytes(whole[:end])
        contents = read_record(cut)
        assert not contents.complete and 'cut short' in contents.problem
        read = [m.message.data for m in contents.messages]
        assert len(read) >= 18 and read == [bool(i % 2) for i in range(len(read))]
