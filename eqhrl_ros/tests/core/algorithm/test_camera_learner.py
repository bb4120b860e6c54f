"""A learner that sees (issue 49, item 2): a state vector and a camera's frame stack, the encoder
trained by the critics' loss alone, the gates on the encoded state, the frames held once in D,
saved and resumed, and every bad input refused with a clear error."""

import dataclasses

import numpy as np
import pytest
import torch

from eqhrl_ros.core.algorithm import equations as eq
from eqhrl_ros.core.algorithm.config import LearnerConfig
from eqhrl_ros.core.algorithm.learner import EQSACLearner
from eqhrl_ros.core.algorithm.stacked_seeds import StackedSeeds
from eqhrl_ros.core.data.errors import CheckpointError
from eqhrl_ros.core.data.frame_replay import FrameReplay
from eqhrl_ros.core.envs.spec import CameraSpec
from eqhrl_ros.core.experts.policy import PolicyExpert, export_policy
from eqhrl_ros.core.runs.checkpoint import load_checkpoint, save_checkpoint

CAMERA = CameraSpec(height=20, width=24, channels=3, stack=2)


def config(**extra) -> LearnerConfig:
    values = dict(mode='eqsac', hidden=(16, 16), batch_size=8, learning_starts=12, queue_length=2, seed=3)
    values.update(extra)
    return LearnerConfig(**values)


def learner(**extra) -> EQSACLearner:
    return EQSACLearner(2, [-2.0], [2.0], config(**extra), camera=CAMERA)


class Frames:
    """Observations of a made-up camera: each frame says its episode and step; stacked as
    gymnasium's FrameStackObservation does, the first frame repeated at an episode's start."""

    def __init__(self):
        self.rng = np.random.default_rng(0)

    def frame(self, episode, step):
        f = self.rng.integers(0, 256, (CAMERA.height, CAMERA.width, CAMERA.channels), dtype=np.uint8)
        f[0, 0, :2] = episode, step
        return f

    def episode(self, episode, length):
        frames = [self.frame(episode, 0)]
        for step in range(length + 1):
            stack = [frames[max(step - 1, 0)], frames[step]]
            yield {'state': np.array([episode, step], np.float32), 'pixels': np.stack(stack)}
            frames.append(self.frame(episode, step + 1))


def run(learner, episodes=3, length=10):
    """Episodes of ``length`` steps through propose and step; returns the proposals."""
    frames, proposals = Frames(), []
    for e in range(episodes):
        observations = list(frames.episode(e, length))
        for t in range(length):
            proposal = learner.propose(observations[t])
            proposals.append(proposal)
            advised = proposal.decision.fire
            learner.step(observations[t], proposal.action, 0.1, observations[t + 1], False, t == length - 1, advised)
    return proposals


def test_a_learner_with_a_camera_acts_asks_and_learns_with_each_frame_held_once():
    one = learner()
    proposals = run(one)
    assert isinstance(one.replay, FrameReplay) and len(one.replay) == 30
    assert one.replay.frames_written == 30 + 3  # one frame a step and each episode's first: held once
    assert one.updates == 30 - 12 + 1 and one.updater.non_finite_updates == 0
    asked = [p for p in proposals if p.decision.fire]
    assert asked and len(one.advice_replay) == len(asked) and one.advice_replay.isolated
    # A request carries the state vector and the stack it asks about, as the learner read it.
    assert all(p.request.observation.shape == (2,) for p in asked)
    assert all(p.request.pixels.shape == CAMERA.stack_shape and p.request.pixels.dtype == np.uint8 for p in asked)
    corners = [p.request.pixels[:, 0, 0, :2].tolist() for p in asked]
    steps = [(p.request.episode, p.request.step) for p in asked]
    assert corners == [[[e, max(t - 1, 0)], [e, t]] for e, t in steps]
    # The stacks D gives back are the ones the learner acted on (the corner pixels say which).
    batch = one.replay.sample(64, torch.Generator().manual_seed(0))
    for i in range(64):
        episode, step = (int(v) for v in batch.vectors.obs[i])
        corners = batch.frames[i].reshape(2, 3, CAMERA.height, CAMERA.width)[:, :2, 0, 0].tolist()
        assert corners == [[episode, max(step - 1, 0)], [episode, step]]


def test_the_gates_read_the_encoded_state():
    """D(s) (Eq. 8) from the twin critics and E(s) (Eq. 9) from the actor, both on the
    encoder's features of the observation, exactly as a vector learner computes them on the vector."""
    one = learner(random_warmup_steps=0)
    run(one, episodes=1)
    obs = next(Frames().episode(7, 3))
    proposal = one.propose(obs)
    with torch.no_grad():
        features = one.observation.encoder(one.observation.tensor(obs))
        assert features.shape == (1, one.observation.features_dim) and torch.equal(
            features[0, :2], torch.tensor([7.0, 0.0])
        )
        mean, log_std = one.actor(features)
        action = torch.as_tensor(one.normalize(proposal.action), dtype=torch.float32).reshape(1, -1)
        q1, q2 = one.critic(features, action)
    assert proposal.decision.discrepancy == pytest.approx(float(eq.q_discrepancy(q1, q2)), rel=1e-4, abs=1e-6)
    assert proposal.decision.entropy == pytest.approx(float(eq.policy_entropy(mean, log_std)), rel=1e-5)


def encoder_weights(one):
    return [p.detach().clone() for p in one.observation.encoder.parameters()]


def test_the_critics_loss_trains_the_encoder_and_the_actors_loss_never_moves_it():
    """DrQ-v2's rule: with the critics' learning rate at its floor (1e-8) the encoder barely
    moves (Adam steps of about 1e-8) while the actor learns at 3e-4 (its loss reads the features
    detached: were they not, the actor's steps would move the encoder by about 1e-4); at the
    critics' usual rate, the encoder moves."""
    still = learner(critic_lr=1e-8)
    before, actor_before = encoder_weights(still), still.actor.heads.weight.detach().clone()
    run(still)
    assert max(float((a - b).abs().max()) for a, b in zip(before, encoder_weights(still))) < 1e-6
    assert float((actor_before - still.actor.heads.weight.detach()).abs().max()) > 1e-4
    moving = learner()
    before = encoder_weights(moving)
    run(moving)
    assert all(not torch.equal(a, b) for a, b in zip(before, encoder_weights(moving)))


def test_a_learner_with_a_camera_saves_and_resumes_with_its_frames(tmp_path):
    one = learner()
    run(one, episodes=2)
    save_checkpoint(one, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    resumed = learner()
    load_checkpoint(resumed, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    assert all(torch.equal(a, b) for a, b in zip(encoder_weights(one), encoder_weights(resumed)))
    assert len(resumed.replay) == 20 and resumed.replay.frames_written == one.replay.frames_written
    assert len(resumed.advice_replay) == len(one.advice_replay)
    obs = next(Frames().episode(5, 2))
    assert np.array_equal(one.act(obs, deterministic=True), resumed.act(obs, deterministic=True))
    assert resumed.update()['critic_loss'] == pytest.approx(one.update()['critic_loss'], rel=1e-5)
    # A checkpoint for other eyes (another camera, or none) is refused, and changes nothing.
    other = EQSACLearner(2, [-2.0], [2.0], config(), camera=CameraSpec(20, 24, 1, 2))
    with pytest.raises(CheckpointError, match='camera'):
        load_checkpoint(other, tmp_path / 'checkpoint.pt')
    with pytest.raises(CheckpointError, match='camera'):
        load_checkpoint(EQSACLearner(2, [-2.0], [2.0], config()), tmp_path / 'checkpoint.pt')


def test_an_exported_camera_policy_carries_its_encoder_and_serves_from_the_frames_a_request_carries(tmp_path):
    one = learner(random_warmup_steps=0)
    run(one, episodes=1)  # the encoder has moved from its first weights
    export_policy(one, tmp_path / 'policy.pt')
    saved = torch.load(tmp_path / 'policy.pt', weights_only=True)
    assert saved['camera'] == {'height': 20, 'width': 24, 'channels': 3, 'stack': 2} and saved['state_dim'] == 2
    assert set(saved['encoder']) == set(one.observation.encoder.state_dict())
    expert = PolicyExpert(tmp_path / 'policy.pt')
    assert expert.observation_size == 2 and expert.camera == CAMERA
    requests = [p.request for p in run(learner(advising_budget=5), episodes=2) if p.request is not None]
    assert requests
    for request in requests:  # the learner's own deterministic action, from the frames asked about
        obs = {'state': request.observation, 'pixels': request.pixels}
        advice = expert(request)
        assert advice.advised and np.allclose(advice.action, one.act(obs, deterministic=True), atol=1e-5)
    frameless = expert(dataclasses.replace(requests[0], pixels=None))
    assert not frameless.advised and 'reads a camera, and the request carries no frames' in frameless.reason


GOOD = next(Frames().episode(0, 1))


@pytest.mark.parametrize(
    'obs, message',
    [
        (np.zeros(2), r"\{'state': vector, 'pixels'"),
        ({'state': np.zeros(2)}, r"'pixels'"),
        ({**GOOD, 'pixels': GOOD['pixels'].astype(np.float32)}, 'must be uint8, got float32'),
        ({**GOOD, 'pixels': GOOD['pixels'][:1]}, r'shape \(1, 20, 24, 3\), the learner reads \(2, 20, 24, 3\)'),
        ({**GOOD, 'pixels': GOOD['pixels'][..., :1]}, r'the learner reads \(2, 20, 24, 3\)'),
        ({**GOOD, 'state': np.array([0.0, np.nan])}, 'non-finite'),
        ({**GOOD, 'state': np.zeros(3)}, 'has 3 values, the learner expects 2'),
    ],
)
def test_a_bad_observation_with_a_camera_is_refused_and_stores_nothing(obs, message):
    one = learner()
    with pytest.raises(ValueError, match=message):
        one.propose(obs)
    with pytest.raises(ValueError, match=message):
        one.step(GOOD, np.zeros(1), 0.0, obs, False, False)
    assert len(one.replay) == 0 and one.replay.frames_written == 0 and one.total_steps == 0


def test_a_replay_capacity_whose_frames_cannot_fit_is_refused_before_anything_is_allocated(monkeypatch):
    from eqhrl_ros.core.algorithm import memories

    monkeypatch.setattr(memories, 'physical_memory_bytes', lambda: 24 * 10**9)
    camera = CameraSpec(84, 84, 3, 3)
    with pytest.raises(
        ValueError,
        match=r'replay_capacity 1,000,000 with 3x84x84 frames needs 44.5 GB .* has 24.0 GB '
        r'\(replay_capacity 269,949 would take half of it\)',
    ):
        EQSACLearner(3, [-2.0], [2.0], config(replay_capacity=1_000_000), camera=camera)
    one = EQSACLearner(3, [-2.0], [2.0], config(replay_capacity=269_949), camera=camera)
    assert one.replay.capacity == 269_949 and one.advice_replay.capacity == 269_949 // 4


def test_what_a_camera_learner_cannot_do_yet_is_refused_with_a_reason():
    with pytest.raises(ValueError, match="mode 'novelty' scores the state vector"):
        learner(mode='novelty')
    with pytest.raises(ValueError, match='at least 15x15'):
        EQSACLearner(2, [-2.0], [2.0], config(), camera=CameraSpec(12, 40))
    with pytest.raises(ValueError, match='channels must be one of'):
        CameraSpec(20, 20, channels=4)
    compiled = learner(compile_update=True)
    run(compiled, episodes=2)
    assert compiled.compiled_update is None and 'stays eager' in compiled.updater.compile_refused
    with pytest.raises(ValueError, match='do not stack the encoder'):
        StackedSeeds([learner(seed=1), learner(seed=2)])
    with pytest.raises(ValueError, match="prior data for a learner with a camera needs each transition's frame stacks"):
        learner().add_prior([GOOD], [[0.0]], [0.0], [GOOD], [False])
