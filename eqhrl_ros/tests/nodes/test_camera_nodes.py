"""A learner that sees, through the nodes (issue 49): gym_env publishes its rendering as a camera
announced in env_info, the learner pairs each observation with its frame and learns from both,
and every bad frame, a camera that stops and a camera that is not there are met as stated."""

import threading

import numpy as np
import pytest
import torch
from rclpy.node import Node
from sensor_msgs.msg import Image

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_interfaces.srv import Advise
from eqhrl_ros.core.data.advice import AdviceRequest
from eqhrl_ros.core.data.transitions import batch_from_fields
from eqhrl_ros.core.envs.spec import CameraSpec, EnvCamera
from eqhrl_ros.files.mcap_record import RecordError, load_prior, read_record
from eqhrl_ros.nodes import advise_msgs, messages
from eqhrl_ros.nodes.camera_input import CameraInput
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.frame_msgs import stack_of
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.messages import EnvStep
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode

from ros_helpers import params, small_learner_params

CAMERA = dict(camera='camera', camera_height=24, camera_width=24, camera_encoding='mono8')


def add_env(harness, ros_context, **extra):
    values = dict(max_episode_steps=20, **CAMERA)
    values.update(extra)
    return harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(**values)))


def camera_learner(ros_context, tmp_path, **extra):
    values = dict(camera='camera', camera_stack=2, learning_starts=30, max_episodes=3, save_replay=True)
    values.update(extra)
    return LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **values))


def frame_msg(height=24, width=24, encoding='mono8', value=7, step=None, data=None) -> Image:
    channels = 1 if encoding == 'mono8' else 3
    row = width * channels if step is None else step
    return Image(
        height=height,
        width=width,
        encoding=encoding,
        step=row,
        data=bytes([value]) * (row * height) if data is None else data,
    )


def test_the_learner_learns_from_the_gym_envs_camera_and_the_vector_beside_it(harness, ros_context, tmp_path):
    env = add_env(harness, ros_context)
    expert = harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    asked, heuristic = [], expert.backend
    expert.backend = lambda request: (asked.append(request), heuristic(request))[1]
    shown = []  # learner/advice_request, as a person's page reads it
    page = harness.add(Node('page', context=ros_context))
    page.create_subscription(AdviceRequestMsg, 'learner/advice_request', shown.append, messages.LATCHED_QOS)
    node = harness.add(camera_learner(ros_context, tmp_path))
    assert harness.spin_until(lambda: node.done, timeout=90)
    learner = node.learner
    assert env.spec.cameras == (EnvCamera('camera', '/camera/image_raw', 24, 24, 'mono8'),)
    assert learner.observation.camera == CameraSpec(24, 24, 1, 2) and learner.observation.state_dim == 3
    assert len(learner.replay) == 60 and learner.replay.frames_written == 60 + 3  # each frame once
    assert learner.updates > 0 and learner.updater.non_finite_updates == 0
    assert learner.advice_total.given > 0 and len(learner.advice_replay) == learner.advice_total.given
    camera = node.camera_input
    assert camera.refused_frames == 0 and camera.untrusted_frames == 0
    # At start-up the first observation can come before the camera's subscription is matched at
    # both ends: it is dropped once, and the env sends it again with its frame (no step lost).
    assert camera.frameless_observations <= 1
    assert camera.stale_frames <= 2  # lock-step: each step's frame comes just before its observation
    assert camera.health_check().message == 'frames arrive on /camera/image_raw'
    # What D holds is what the env showed: the pendulum moves, so its frames differ, and none is blank.
    frames = learner.replay.frames[: learner.replay.frames_written]
    assert len({f.tobytes() for f in frames}) > 30 and all(f.any() for f in frames)
    saved = torch.load(tmp_path / 'checkpoint.pt', weights_only=True)
    assert saved['camera'] == {'height': 24, 'width': 24, 'channels': 1, 'stack': 2}
    # Each request carries the stack it asks about, as the learner read it, to the expert and the page.
    assert len(asked) == learner.advice_total.asked
    assert all(r.pixels.shape == (2, 24, 24, 1) and r.pixels[-1].any() for r in asked)
    assert harness.spin_until(lambda: len({(m.episode, m.step) for m in shown}) == len(asked), timeout=10)
    for request in asked:
        frames = [m.frames for m in shown if (m.episode, m.step) == (request.episode, request.step)]
        assert frames and all(np.array_equal(stack_of(f), request.pixels) for f in frames)
        assert [(f.encoding, f.height, f.width) for f in frames[0]] == [('mono8', 24, 24)] * 2


def test_while_a_stranger_publishes_on_the_camera_topic_no_frame_is_taken(harness, ros_context, tmp_path):
    """A second publisher on the camera's topic (it could show the learner anything): no frame is
    taken from either while both publish, so no observation can be acted on; once the stranger
    leaves, the learner takes the env's frames and learns."""
    stranger = Node('stranger', context=ros_context)
    stranger.create_publisher(Image, '/camera/image_raw', 10)
    node = harness.add(camera_learner(ros_context, tmp_path, max_episodes=2, camera_wait_s=0.05))
    try:
        assert harness.spin_until(lambda: node.count_publishers('/camera/image_raw') == 1, timeout=10)
        add_env(harness, ros_context)
        assert harness.spin_until(lambda: node.camera_input is not None and node.camera_input.untrusted_frames > 1)
        assert harness.spin_until(lambda: node.camera_input.frameless_observations > 1, timeout=10)
        assert node.camera_input.received == 0 and node.learner.total_steps == 0  # nothing taken, nothing learned
        assert node.camera_input.health_check().message.startswith(
            "frames refused: '/camera/image_raw' has 2 publishers"
        )
    finally:
        stranger.destroy_node()
    assert harness.spin_until(lambda: node.done, timeout=90)
    assert len(node.learner.replay) == 40 and node.camera_input.received > 40


def test_a_learner_told_a_camera_the_env_does_not_announce_stops_saying_which_it_has(harness, ros_context, tmp_path):
    add_env(harness, ros_context, camera='')
    node = harness.add(camera_learner(ros_context, tmp_path, camera='front'))
    assert harness.spin_until(lambda: getattr(node, 'exit_error', None), timeout=30)
    assert "the env announces no camera 'front' (its cameras: none)" in node.exit_error


@pytest.mark.parametrize('topic', ['bad topic!', '2d/front', 'front/', 'a//b', '~x', 'cam/{node}', 'c' * 256])
def test_a_camera_topic_that_is_no_ros_name_is_refused_in_one_line(topic):
    with pytest.raises(ValueError, match='is not a ROS topic name') as refused:
        EnvCamera('camera', topic, 24, 24, 'mono8')
    assert len(str(refused.value)) < 300
    for good in ('camera', '/robot/front_cam', '~/image_raw', 'c' * 255):
        assert EnvCamera('camera', good, 24, 24, 'mono8').topic == good
    with pytest.raises(ValueError, match='camera name'):
        EnvCamera('front\x1b[2J', 'camera', 24, 24, 'mono8')


def test_a_learner_refuses_an_env_info_whose_camera_topic_is_no_ros_name(harness, ros_context, tmp_path):
    """Before, the learner subscribed to the announced topic as it started, rclpy raised there, and
    the node stopped with a traceback."""
    import rclpy
    from std_msgs.msg import Float32MultiArray

    from eqhrl_interfaces.msg import CameraPart, EnvInfo
    from eqhrl_ros.nodes import env_info

    env = harness.add(rclpy.create_node('fake_env', context=ros_context))
    env.create_publisher(Float32MultiArray, 'observation', 10)
    camera = CameraPart(name='camera', topic='bad topic!', height=24, width=24, encoding='mono8')
    msg = EnvInfo(
        publisher='/fake_env',
        name='cam_env',
        observation_size=3,
        action_size=1,
        action_low=[-2.0],
        action_high=[2.0],
        cameras=[camera],
    )
    env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(msg)
    node = harness.add(camera_learner(ros_context, tmp_path))
    assert harness.spin_until(lambda: getattr(node, 'exit_error', None), timeout=15)
    assert "topic 'bad topic!' is not a ROS topic name" in node.exit_error and node.learner is None


def test_the_record_holds_each_frame_once_and_a_later_camera_learner_takes_its_advice_with_the_frames(
    harness, ros_context, tmp_path
):
    """record: true with a camera: each episode's TransitionBatch carries its frames once (PNG,
    lossless) with each transition's stack by index, read back by mcap and by rosbags; a later
    camera learner's prior takes the advised transitions with the very stacks they were asked on,
    and a learner without a camera (or with another) refuses that record in one line."""
    add_env(harness, ros_context)
    expert = harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    asked, heuristic = [], expert.backend
    expert.backend = lambda request: (asked.append(request), heuristic(request))[1]
    first = harness.add(camera_learner(ros_context, tmp_path / 'first', record=True, max_episodes=2))
    assert harness.spin_until(lambda: first.done, timeout=90)
    first.close()
    given = first.learner.advice_total.given
    assert given > 0 and given == len(asked)  # the heuristic answers every request

    batches = [m.message for m in read_record(tmp_path / 'first' / 'record.mcap').on('/learner/transitions')]
    frames = [batch_from_fields(b)[0].frames for b in batches]
    assert [len(b.rewards) for b in batches] == [20, 20]
    assert all(b.frame_stack == 2 and {f.format for f in b.frames} == {'png'} for b in batches)
    # Each frame once: at most a step's and the episode's first (two steps may show the same picture).
    assert all(15 < len(f.frames) <= 21 for f in frames)
    assert len({frame.tobytes() for f in frames for frame in f.frames}) > 30  # the pendulum moves
    from rosbags.highlevel import AnyReader

    with AnyReader([tmp_path / 'first' / 'record.mcap']) as reader:
        connections = [c for c in reader.connections if c.topic == '/learner/transitions']
        read = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]
    assert [len(m.frames) for m in read] == [len(f.frames) for f in frames] and read[0].frames[0].format == 'png'

    # Advised transitions, in order, carry the stacks the requests were about.
    advised = np.concatenate([f.observation_stacks()[np.asarray(b.advised, bool)] for f, b in zip(frames, batches)])
    assert np.array_equal(advised, np.stack([r.pixels for r in asked]))

    prior = str(tmp_path / 'first')
    second = harness.add(camera_learner(ros_context, tmp_path / 'second', prior=[prior], max_episodes=1))
    assert harness.spin_until(lambda: second.learner is not None, timeout=30)
    memory = second.learner.advice_replay
    assert len(memory) == len(second.learner.replay) == given and second.learner.total_steps == 0
    held = memory.frames[: memory.frames_written].reshape(given, 3, 1, 24, 24).transpose(0, 1, 3, 4, 2)
    assert np.array_equal(held[:, :2], advised)  # each advised step: its stack, then its next frame

    with pytest.raises(RecordError, match='recorded with a camera; this learner has none'):
        load_prior([prior], 3, [-2.0], [2.0])
    third = harness.add(camera_learner(ros_context, tmp_path / 'third', prior=[prior], camera_stack=3))
    assert harness.spin_until(lambda: getattr(third, 'exit_error', None), timeout=30)
    assert 'recorded with 2 frames of 24x24x1; this learner reads 3 of 24x24x1' in third.exit_error


class Retries:
    def __init__(self):
        self.data = []

    def __call__(self, data):
        self.data.append(data)


@pytest.fixture
def camera_input(harness, ros_context):
    """A CameraInput on a bare node, fed by a publisher node: the pairing rule alone."""
    node = harness.add(Node('camera_reader', context=ros_context))
    publisher = harness.add(Node('camera_driver', context=ros_context)).create_publisher(Image, '/cam', 10)
    retries = Retries()
    camera = CameraInput(node, EnvCamera('cam', '/cam', 24, 24, 'mono8'), 3, 0.2, threading.RLock(), retries)
    assert harness.spin_until(lambda: publisher.get_subscription_count() > 0, timeout=10)
    return camera, publisher, retries


def step(episode, index):
    return EnvStep(np.zeros(3, np.float32), 0.0, False, False, episode, index)


def test_an_observation_takes_the_newest_frame_after_the_last_one_used_and_stacks_restart(harness, camera_input):
    camera, publisher, retries = camera_input
    publisher.publish(frame_msg(value=1))
    assert harness.spin_until(lambda: camera.received == 1)
    first = camera.attach(step(0, 0), b'a')
    assert [int(f[0, 0, 0]) for f in first.obs['pixels']] == [1, 1, 1]  # an episode's start: repeated
    for value in (2, 3):
        publisher.publish(frame_msg(value=value))
    assert harness.spin_until(lambda: camera.received == 3)
    second = camera.attach(step(0, 1), b'b')
    assert [int(f[0, 0, 0]) for f in second.obs['pixels']] == [1, 1, 3]  # the newest
    # Late: no new frame yet, so the observation waits; its frame comes, and it is acted on.
    late = b'c'
    assert camera.attach(step(0, 2), late) is None
    publisher.publish(frame_msg(value=4))
    assert harness.spin_until(lambda: retries.data == [late])
    third = camera.attach(step(0, 2), late)
    assert [int(f[0, 0, 0]) for f in third.obs['pixels']] == [1, 3, 4]
    # Missing: none comes within camera_wait_s; the newest stands in, counted as stale.
    missing = b'd'
    assert camera.attach(step(0, 3), missing) is None
    assert harness.spin_until(lambda: retries.data[-1] is missing, timeout=5)
    fourth = camera.attach(step(0, 3), missing)
    assert camera.stale_frames == 1
    assert [int(f[0, 0, 0]) for f in fourth.obs['pixels']] == [3, 4, 4]
    # A step that does not follow (one was lost) starts the stack over, as D rebuilds it.
    publisher.publish(frame_msg(value=9))
    assert harness.spin_until(lambda: camera.received == 5)
    after_gap = camera.attach(step(0, 6), b'e')
    assert [int(f[0, 0, 0]) for f in after_gap.obs['pixels']] == [9, 9, 9]


def test_frames_that_do_not_fit_the_announcement_are_refused_and_change_nothing(harness, camera_input):
    camera, publisher, _ = camera_input
    publisher.publish(frame_msg(value=5))
    assert harness.spin_until(lambda: camera.received == 1)
    bad = [
        frame_msg(height=48),  # another size
        frame_msg(encoding='rgb8'),  # another encoding
        frame_msg(data=b'\x00' * 10),  # fewer bytes than its header says
        frame_msg(step=10),  # rows shorter than the width
        frame_msg(height=40000, width=40000, data=b''),  # would be gigabytes
    ]
    for msg in bad:
        publisher.publish(msg)
    assert harness.spin_until(lambda: camera.refused_frames == len(bad))
    assert camera.received == 1 and int(camera.latest[0, 0, 0]) == 5


def test_with_no_frame_ever_an_observation_is_dropped_after_the_wait(harness, camera_input):
    camera, _, retries = camera_input
    data = b'x'
    assert camera.attach(step(0, 0), data) is None
    assert harness.spin_until(lambda: retries.data == [data], timeout=5)
    assert camera.attach(step(0, 0), data) is None and camera.frameless_observations == 1


def test_compressed_frames_are_decoded_once_their_declared_size_is_the_announced_one(harness, ros_context):
    """camera_transport compressed: JPEG or PNG on <topic>/compressed (image_transport's name).
    A good one is decoded and kept; one of another size, one that does not decode and one whose
    header declares 40000x40000 pixels are refused, the last before anything is decoded."""
    import io

    from PIL import Image as PILImage
    from sensor_msgs.msg import CompressedImage

    node = harness.add(Node('camera_reader', context=ros_context))
    driver = harness.add(Node('camera_driver', context=ros_context))
    publisher = driver.create_publisher(CompressedImage, '/cam/compressed', 10)
    camera = CameraInput(
        node, EnvCamera('cam', '/cam', 24, 24, 'mono8'), 3, 0.2, threading.RLock(), Retries(), transport='compressed'
    )
    assert harness.spin_until(lambda: publisher.get_subscription_count() > 0, timeout=10)

    def encoded(size, fmt='PNG', value=9):
        out = io.BytesIO()
        PILImage.fromarray(np.full(size, value, np.uint8)).save(out, format=fmt)
        return out.getvalue()

    publisher.publish(CompressedImage(format='png', data=encoded((24, 24))))
    assert harness.spin_until(lambda: camera.received == 1)
    assert camera.latest.shape == (24, 24, 1) and (camera.latest == 9).all()
    bomb = bytearray(encoded((1, 1)))
    bomb[16:24] = (40000).to_bytes(4, 'big') * 2  # the IHDR's width and height
    for data in (encoded((32, 24)), b'not an image', bytes(bomb), encoded((24, 24, 3), 'JPEG')):
        publisher.publish(CompressedImage(format='png', data=data))
    assert harness.spin_until(lambda: camera.refused_frames == 4)
    assert camera.received == 1 and camera.health_check().message == 'frames arrive on /cam/compressed'


def advise_with_frames(frames) -> Advise.Request:
    request = AdviceRequest(
        np.zeros(3, np.float32), np.zeros(1, np.float32), np.array([-2.0], np.float32),
        np.array([2.0], np.float32), 0.1, -1.0, 0, 4,
        pixels=np.arange(2 * 24 * 24, dtype=np.uint32).astype(np.uint8).reshape(2, 24, 24, 1),
    )  # fmt: skip
    msg = advise_msgs.request_msg(request, timeout_s=5.0)
    assert np.array_equal(advise_msgs.request_from_msg(msg).pixels, request.pixels)  # what the learner sends
    if frames is not None:
        msg.frames = frames
    return msg


EXPERTS = {
    'controller': lambda context: ExpertNode(context=context, parameter_overrides=params(env_id='Pendulum-v1')),
    'simulated person': lambda context: ExpertNode(
        context=context,
        parameter_overrides=params(env_id='Pendulum-v1', backend='simulated_human', reaction_median_s=0.01),
    ),
    'teleop, answer window': lambda context: TeleopExpertNode(
        context=context, parameter_overrides=params(source='array', answer_window_s=0.3)
    ),
}


@pytest.mark.parametrize('expert', EXPERTS)
def test_an_expert_declines_a_request_whose_frames_cannot_be_one_stack_and_answers_the_next(
    harness, ros_context, expert
):
    """Frames come from another node: a stack of two sizes, or bytes that do not fit a header,
    is declined saying why (never an exception in the service), and the next request is answered."""
    harness.add(EXPERTS[expert](ros_context))
    client = harness.add(Node('asker', context=ros_context)).create_client(Advise, 'advise')
    assert harness.spin_until(client.service_is_ready, timeout=10)

    def call(frames):
        future = client.call_async(advise_with_frames(frames))
        assert harness.spin_until(future.done, timeout=10)
        return future.result()

    for bad, reason in (
        ([frame_msg(), frame_msg(height=23)], 'frames refused: the frames of a stack differ in encoding or size'),
        ([frame_msg(data=b'short')], 'frames refused: frame holds 5 bytes, its header says 24 x 24 = 576'),
    ):
        answer = call(bad)
        assert not answer.advised and answer.reason.startswith(reason)
    answer = call(None)
    assert answer.advised or answer.timed_out or answer.reason  # answered as the backend answers, not refused
    assert not answer.reason.startswith('frames refused')


def test_a_signed_batch_covers_its_frames():
    """With a key_file, a batch's signature covers its frames and their indexes: a frame
    altered on the way is refused like any other altered field."""
    from eqhrl_ros.core.data.signing import Signer
    from eqhrl_ros.core.data.transitions import BatchFrames, TransitionBatch
    from eqhrl_ros.nodes.trainer_msgs import batch_msg, sign_batch, signature_refusal

    stacks = np.random.default_rng(0).integers(0, 256, (2, 2, 24, 24, 1), dtype=np.uint8)
    frames = BatchFrames.of(stacks, stacks[:, -1])
    zeros = np.zeros((2, 3), np.float32)
    batch = TransitionBatch('a', 0, zeros, np.zeros((2, 1), np.float32), np.zeros(2, np.float32), zeros,
                            np.zeros(2, bool), np.ones(2, bool), frames=frames)  # fmt: skip
    signer = Signer(bytes(range(32)))
    for alter in (
        lambda msg: msg.frames[0].data.__setitem__(40, msg.frames[0].data[40] ^ 1),
        lambda msg: msg.next_frames.__setitem__(0, 1 - msg.next_frames[0]),
        lambda msg: setattr(msg, 'frame_stack', 1),
    ):
        msg = sign_batch(batch_msg(batch, [-2.0], [2.0]), signer)
        assert signature_refusal(msg, signer) == ''
        alter(msg)
        assert 'altered on the way' in signature_refusal(msg, signer)
