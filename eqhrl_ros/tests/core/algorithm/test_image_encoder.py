"""The image encoder and random-shift augmentation (issue 49, item 2)."""

import pytest
import torch

from eqhrl_ros.core.algorithm.image_encoder import ImageEncoder, conv_output_size, random_shift


def test_the_encoder_reads_uint8_stacks_and_its_dim_is_what_it_gives():
    encoder = ImageEncoder(9, 84, 84)  # three stacked RGB frames
    features = encoder(torch.randint(0, 256, (5, 9, 84, 84), dtype=torch.uint8))
    assert features.shape == (5, encoder.dim) and encoder.dim == 32 * 35 * 35  # DrQ-v2's 84x84: 35x35x32
    assert conv_output_size(84) == 35


@pytest.mark.parametrize(
    'frames, message',
    [
        (torch.zeros(2, 9, 84, 84), 'uint8'),  # float frames, not the camera's bytes
        (torch.zeros(2, 3, 84, 84, dtype=torch.uint8), 'uint8 \\[B, 9, 84, 84\\]'),  # one frame, not three
        (torch.zeros(2, 9, 64, 84, dtype=torch.uint8), '64, 84'),
    ],
)
def test_the_encoder_refuses_frames_of_another_kind_saying_what_it_reads(frames, message):
    with pytest.raises(ValueError, match=message):
        ImageEncoder(9, 84, 84)(frames)


def test_frames_too_small_for_the_convolutions_are_refused_and_the_smallest_is_said():
    with pytest.raises(ValueError, match='too small for the encoder \\(at least 15x15\\)'):
        ImageEncoder(3, 14, 84)
    assert ImageEncoder(3, 15, 15).dim == 32  # one pixel of each filter left


def test_a_detached_read_leaves_the_encoder_to_the_critics_loss():
    """The actor reads the encoder's output detached: its loss gives the encoder no gradient."""
    encoder = ImageEncoder(3, 16, 16)
    head = torch.nn.Linear(encoder.dim, 1)
    frames = torch.randint(0, 256, (4, 3, 16, 16), dtype=torch.uint8)
    head(encoder(frames).detach()).sum().backward()
    assert all(p.grad is None for p in encoder.parameters())
    head(encoder(frames)).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in encoder.parameters())


def test_random_shift_crops_each_image_of_its_padded_self_at_its_own_offset():
    pad = 4
    frames = torch.randint(0, 256, (64, 3, 12, 10), dtype=torch.uint8)
    shifted = random_shift(frames, pad, torch.Generator().manual_seed(0))
    assert shifted.dtype == torch.uint8 and shifted.shape == frames.shape
    padded = torch.nn.functional.pad(frames.float(), (pad,) * 4, mode='replicate').to(torch.uint8)
    offsets = []
    for image, source in zip(shifted, padded, strict=True):
        found = [
            (dy, dx)
            for dy in range(2 * pad + 1)
            for dx in range(2 * pad + 1)
            if torch.equal(source[:, dy : dy + 12, dx : dx + 10], image)
        ]
        assert found, 'a shifted image is no crop of its padded self'
        offsets.append(found[0])
    assert len(set(offsets)) > 20  # each image its own offset, not one for the batch
    again = random_shift(frames, pad, torch.Generator().manual_seed(0))
    assert torch.equal(again, shifted)  # drawn from the given stream only
    assert torch.equal(random_shift(frames, 0, torch.Generator()), frames)


def test_a_large_batch_through_the_encoder_in_chunks_gives_each_image_its_own_features_and_gradients():
    """On the CPU the convolutions take CPU_CHUNK images at a time (a cache effect, measured in
    ImageEncoder.scaled): every image's features and the weights' gradient are those of one pass."""
    from eqhrl_ros.core.algorithm.image_encoder import CPU_CHUNK

    torch.manual_seed(0)
    encoder = ImageEncoder(6, 20, 20)
    x = torch.rand(2 * CPU_CHUNK + 5, 6, 20, 20) - 0.5
    chunked = encoder.scaled(x)
    whole = encoder.convs(x).flatten(1)
    assert chunked.shape == whole.shape and torch.allclose(chunked, whole, atol=1e-6)
    weight = encoder.convs[0].weight
    (grad_chunked,) = torch.autograd.grad(encoder.scaled(x).square().sum(), weight)
    (grad_whole,) = torch.autograd.grad(encoder.convs(x).flatten(1).square().sum(), weight)
    assert torch.allclose(grad_chunked, grad_whole, rtol=1e-4, atol=1e-4)
