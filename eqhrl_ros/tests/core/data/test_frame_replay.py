"""The frame replay memory (issue 49, item 3): each frame held once, stacks gathered by index,
clamped at an episode's start, bounded, saved and loaded, and bad frames refused."""

import numpy as np
import pytest
import torch

from eqhrl_ros.core.data.frame_replay import FrameReplay, frame_bytes, frame_slots

SHAPE = (3, 4, 5)  # (C, H, W)
STACK = 3


def frame(episode: int, step: int) -> np.ndarray:
    """An (H, W, C) frame that says which episode and step it shows: channel 0, channel 1."""
    f = np.zeros((SHAPE[1], SHAPE[2], SHAPE[0]), np.uint8)
    f[..., 0], f[..., 1] = episode, step
    return f


def fill(memory: FrameReplay, episodes: list[int], first_episode: int = 0) -> None:
    """Episodes of the given lengths; a transition's vector is (episode, step it starts from)."""
    for e, length in enumerate(episodes, start=first_episode):
        memory.start_episode(frame(e, 0))
        for t in range(length):
            memory.add([e, t], [0.5], 1.0, frame(e, t + 1), [e, t + 1], terminated=t == length - 1)


def shown(stack: torch.Tensor) -> list[tuple[int, int]]:
    """(episode, step) of each frame in one [k*C, H, W] stack, oldest first."""
    frames = stack.reshape(STACK, *SHAPE)
    return [(int(f[0, 0, 0]), int(f[1, 0, 0])) for f in frames]


def expected(episode: int, step: int) -> list[tuple[int, int]]:
    """The last STACK frames up to ``step``, the reset frame repeated before the episode began."""
    return [(episode, max(step - m, 0)) for m in range(STACK - 1, -1, -1)]


def check_batch(batch) -> None:
    for i in range(batch.frames.shape[0]):
        episode, step = (int(v) for v in batch.vectors.obs[i])
        assert shown(batch.frames[i]) == expected(episode, step)
        assert shown(batch.next_frames[i]) == expected(episode, step + 1)
        assert batch.vectors.next_obs[i].tolist() == [episode, step + 1]


def test_stacks_are_the_episodes_last_frames_and_repeat_the_reset_frame_at_its_start():
    memory = FrameReplay(200, SHAPE, STACK, vector_dim=2, action_dim=1)
    fill(memory, [1, 2, 7, 30])
    batch = memory.sample(512, torch.Generator().manual_seed(0))
    assert batch.frames.dtype == torch.uint8 and tuple(batch.frames.shape) == (512, STACK * SHAPE[0], *SHAPE[1:])
    check_batch(batch)
    starts = {int(v) for v in batch.vectors.obs[:, 1]}
    assert 0 in starts and 29 in starts  # both an episode's first and a long episode's last step came up


def test_each_frame_is_held_once_and_the_bound_is_what_the_docstring_says():
    memory = FrameReplay(1000, SHAPE, STACK, vector_dim=2, action_dim=1)
    assert memory.frames.nbytes == frame_bytes(1000, SHAPE) == frame_slots(1000) * int(np.prod(SHAPE))
    fill(memory, [99] * 10)
    assert memory.frames_written == 10 * 100  # one frame per step and one per episode start, not 2k per step
    # Issue 49's target: 100,000 transitions of three stacked 84x84 RGB frames in under 2.5 GB.
    assert frame_bytes(100_000, (3, 84, 84)) < 2.5e9


def test_after_the_ring_wraps_no_stack_shows_an_overwritten_frame():
    memory = FrameReplay(40, SHAPE, STACK, vector_dim=2, action_dim=1)
    fill(memory, [3, 1, 2, 1] * 20 + [25, 4])  # short episodes: more frames than rows, wrapped many times
    check_batch(memory.sample(2000, torch.Generator().manual_seed(1)))


def test_a_bad_frame_or_transition_is_refused_and_nothing_is_stored():
    memory = FrameReplay(10, SHAPE, STACK, vector_dim=2, action_dim=1)
    with pytest.raises(ValueError, match='start_episode'):
        memory.add([0, 0], [0.0], 0.0, frame(0, 1), [0, 1], False)
    with pytest.raises(ValueError, match='uint8'):
        memory.start_episode(frame(0, 0).astype(np.float32))
    with pytest.raises(ValueError, match=r'\(H, W, C\)'):
        memory.start_episode(np.zeros((SHAPE[2], SHAPE[1], SHAPE[0]), np.uint8))  # W and H swapped
    memory.start_episode(frame(0, 0))
    written = memory.frames_written
    with pytest.raises(ValueError, match='non-finite'):
        memory.add([np.nan, 0], [0.0], 0.0, frame(0, 1), [0, 1], False)
    with pytest.raises(ValueError, match='shape'):
        memory.add([0, 0], [0.0], 0.0, frame(0, 1)[:, :, :2], [0, 1], False)
    assert (len(memory), memory.frames_written) == (0, written)


def test_a_saved_memory_loads_into_a_new_one_and_samples_the_same():
    memory = FrameReplay(40, SHAPE, STACK, vector_dim=2, action_dim=1)
    fill(memory, [3, 1, 2] * 10 + [12])
    loaded = FrameReplay(40, SHAPE, STACK, vector_dim=2, action_dim=1)
    loaded.load_state_dict(memory.state_dict())
    a = memory.sample(300, torch.Generator().manual_seed(2))
    b = loaded.sample(300, torch.Generator().manual_seed(2))
    assert torch.equal(a.frames, b.frames) and torch.equal(a.next_frames, b.next_frames)
    assert torch.equal(a.vectors.obs, b.vectors.obs)
    fill(loaded, [5], first_episode=9)  # it goes on where the saved one stopped
    check_batch(loaded.sample(300, torch.Generator().manual_seed(3)))


def test_an_episode_longer_than_the_ring_saves_loads_and_goes_on():
    memory = FrameReplay(20, SHAPE, STACK, vector_dim=2, action_dim=1)
    memory.start_episode(frame(0, 0))
    for t in range(60):  # its reset frame is long overwritten
        memory.add([0, t], [0.5], 1.0, frame(0, t + 1), [0, t + 1], terminated=False)
    loaded = FrameReplay(20, SHAPE, STACK, vector_dim=2, action_dim=1)
    loaded.load_state_dict(memory.state_dict())
    for t in range(60, 64):
        loaded.add([0, t], [0.5], 1.0, frame(0, t + 1), [0, t + 1], terminated=False)
    check_batch(loaded.sample(200, torch.Generator().manual_seed(4)))


@pytest.mark.parametrize(
    'corrupt, message',
    [
        (lambda s: s.update(frames=s['frames'].float()), 'uint8'),
        (lambda s: s.update(next_frame=s['next_frame'] + 10_000), 'never written'),
        (lambda s: s.update(episode_first=s['episode_first'] + 10_000), 'episode start after'),
        (lambda s: s.update(first=-5), 'episode start'),
        (lambda s: s.update(stack=STACK + 1), 'stacks'),
        (lambda s: s['vectors'].update(reward=s['vectors']['reward'] * np.nan), 'non-finite'),
    ],
)
def test_a_corrupt_saved_memory_is_refused_and_the_memory_is_left_as_it_was(corrupt, message):
    memory = FrameReplay(20, SHAPE, STACK, vector_dim=2, action_dim=1)
    fill(memory, [4, 4])
    target = FrameReplay(20, SHAPE, STACK, vector_dim=2, action_dim=1)
    fill(target, [6], first_episode=7)
    before = target.state_dict()
    state = memory.state_dict()
    corrupt(state)
    with pytest.raises(ValueError, match=message):
        target.load_state_dict(state)
    after = target.state_dict()
    assert torch.equal(after['frames'], before['frames']) and after['frames_written'] == before['frames_written']
    assert torch.equal(after['vectors']['obs'], before['vectors']['obs'])


def test_isolated_transitions_keep_the_stacks_they_were_given_and_their_bound():
    """D_advising's memory: advised steps come one by one (steps 5 and 9 of one episode), each
    stored with its own stack, which no later step overwrites; stack + 1 frames a transition."""
    memory = FrameReplay(50, SHAPE, STACK, vector_dim=2, action_dim=1, isolated=True)
    assert memory.slots == 50 * (STACK + 1)
    for step in (5, 9, 4):
        stack = np.stack([frame(2, s) for s in (step - 2, step - 1, step)])
        memory.add_stacked([2, step], [0.0], 1.0, stack, frame(2, step + 1), [2, step + 1], terminated=False)
    check_batch(memory.sample(64, torch.Generator().manual_seed(1)))
    batch = memory.sample(3, torch.Generator().manual_seed(1), replacement=False)
    assert sorted(int(v) for v in batch.vectors.obs[:, 1]) == [4, 5, 9]
    with pytest.raises(ValueError, match='a stack of 3 frames'):
        memory.add_stacked([2, 1], [0.0], 1.0, frame(2, 1)[None], frame(2, 2), [2, 2], terminated=False)
    with pytest.raises(ValueError, match='non-finite'):
        stack = np.stack([frame(2, 0)] * STACK)
        memory.add_stacked([2, np.nan], [0.0], 1.0, stack, frame(2, 1), [2, 1], terminated=False)
    assert len(memory) == 3 and memory.frames_written == 3 * (STACK + 1)  # refused ones wrote nothing
    fresh = memory.empty()
    fresh.load_state_dict(memory.state_dict())
    assert fresh.isolated and len(fresh) == 3
    with pytest.raises(ValueError, match='isolated'):
        FrameReplay(50, SHAPE, STACK, vector_dim=2, action_dim=1).load_state_dict(memory.state_dict())
