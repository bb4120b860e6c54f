"""Camera frames checked by meaning (core/data/camera_frames.py): raw sensor_msgs/Image fields
to pixels, compressed frames decoded without trusting their header."""

import io
import re
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from eqhrl_ros.core.data import camera_frames
from eqhrl_ros.core.data.camera_frames import (
    MAX_FRAME_PIXELS,
    FrameError,
    decode_compressed,
    frame_array,
    jpeg_bytes,
)

RGB = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)  # (H, W, C)


def test_rgb_bgr_and_mono_frames_come_out_as_rgb_or_mono_pixels_padded_rows_included():
    assert np.array_equal(frame_array('rgb8', 2, 3, 9, RGB.tobytes()), RGB)
    assert np.array_equal(frame_array('bgr8', 2, 3, 9, RGB[:, :, ::-1].tobytes()), RGB)
    padded = np.concatenate([RGB.reshape(2, 9), np.full((2, 3), 255, np.uint8)], axis=1)  # step 12
    assert np.array_equal(frame_array('rgb8', 2, 3, 12, padded.tobytes()), RGB)
    mono = frame_array('mono8', 2, 3, 3, bytes(range(6)))
    assert mono.shape == (2, 3, 1) and mono[1, 2, 0] == 5


@pytest.mark.parametrize(
    'fields, message',
    [
        (('rgba16', 2, 3, 24, bytes(48)), "encoding 'rgba16' is not one of rgb8, bgr8, mono8"),
        (('rgb8', 0, 3, 9, b''), 'empty'),
        (('rgb8', 2, 3, 6, bytes(12)), 'step 6 is shorter than a row'),
        (('rgb8', 2, 3, 9, bytes(17)), 'holds 17 bytes, its header says 9 x 2 = 18'),
        (('rgb8', 2, 3, 9, bytes(19)), 'holds 19 bytes'),
        (('mono8', 65536, 65536, 65536, b''), 'over the limit'),  # refused before any allocation
    ],
)
def test_a_raw_frame_that_does_not_fit_its_header_is_refused_saying_why(fields, message):
    with pytest.raises(FrameError, match=message):
        frame_array(*fields)


def encoded(array: np.ndarray, fmt: str) -> bytes:
    out = io.BytesIO()
    Image.fromarray(array.squeeze()).save(out, format=fmt)
    return out.getvalue()


def test_png_decodes_exactly_and_jpeg_closely():
    frame = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    assert np.array_equal(decode_compressed(encoded(frame, 'PNG')), frame)
    smooth = np.broadcast_to(np.linspace(0, 255, 32, dtype=np.uint8)[None, :, None], (24, 32, 3)).copy()
    back = decode_compressed(jpeg_bytes(smooth, 95))
    assert back.shape == (24, 32, 3) and np.abs(back.astype(int) - smooth).max() < 12
    mono = decode_compressed(encoded(smooth[:, :, :1], 'PNG'))
    assert mono.shape == (24, 32, 1) and np.array_equal(mono, smooth[:, :, :1])


def png_declaring(width: int, height: int) -> bytes:
    """A small PNG whose header says it is ``width`` x ``height`` (a decompression bomb's header)."""
    data = bytearray(encoded(np.zeros((2, 2, 3), np.uint8), 'PNG'))
    ihdr = 8 + 8  # signature, then the IHDR chunk's length and type
    data[ihdr : ihdr + 8] = struct.pack('>II', width, height)
    crc = zlib.crc32(bytes(data[ihdr - 4 : ihdr + 13]))
    data[ihdr + 13 : ihdr + 17] = struct.pack('>I', crc)
    return bytes(data)


def test_a_compressed_frame_that_would_decode_to_gigabytes_is_refused_from_its_header():
    with pytest.raises(FrameError, match=f'over the limit of {MAX_FRAME_PIXELS} pixels'):
        decode_compressed(png_declaring(8_000, 8_000))  # 192 MB of RGB: ours refuses it
    with pytest.raises(FrameError, match='over the limit'):
        decode_compressed(png_declaring(60_000, 60_000))  # 10.8 GB: pillow's own guard is first
    with pytest.raises(FrameError, match='64x64 pixels is over the limit of 4000 pixels'):
        decode_compressed(encoded(np.zeros((64, 64, 3), np.uint8), 'PNG'), max_pixels=4000)


@pytest.mark.parametrize(
    'data, message',
    [
        (b'not an image at all', 'does not decode'),
        (jpeg_bytes(np.zeros((40, 40, 3), np.uint8), 80)[:200], 'does not decode'),  # cut off mid-way
        (encoded(np.zeros((4, 4, 3), np.uint8), 'GIF'), 'GIF, not JPEG or PNG'),
    ],
)
def test_a_compressed_frame_that_does_not_decode_is_refused_saying_why(data, message):
    with pytest.raises(FrameError, match=message):
        decode_compressed(data)


def test_a_stack_goes_out_as_raw_frames_and_comes_back_pixel_for_pixel_and_as_one_lossless_png():
    rng = np.random.default_rng(1)
    for channels in (1, 3):
        stack = rng.integers(0, 256, (3, 5, 7, channels), dtype=np.uint8)
        fields = [camera_frames.frame_fields(frame) for frame in stack]
        assert [f[0] for f in fields] == ['mono8' if channels == 1 else 'rgb8'] * 3
        assert np.array_equal(camera_frames.stack_array(fields), stack)
        shown = np.asarray(Image.open(io.BytesIO(camera_frames.png_bytes(stack))))
        side_by_side = np.concatenate(list(stack), axis=1)  # oldest left
        assert np.array_equal(shown.reshape(side_by_side.shape), side_by_side)
    with pytest.raises(FrameError, match=r'uint8 \(H, W, 1 or 3\)'):
        camera_frames.frame_fields(np.zeros((5, 7, 2), np.uint8))


def raw(height, width, encoding='mono8', count=1):
    channels = camera_frames.ENCODINGS[encoding]
    return [(encoding, height, width, width * channels, bytes(height * width * channels))] * count


@pytest.mark.parametrize(
    'frames, message',
    [
        ([], 'a stack holds 1 to 16 frames, got 0'),
        (raw(4, 4, count=17), 'a stack holds 1 to 16 frames, got 17'),
        (raw(4, 4) + raw(4, 5), 'the frames of a stack differ in encoding or size'),
        (raw(4, 4) + raw(4, 4, 'rgb8'), 'the frames of a stack differ in encoding or size'),
        (raw(4096, 4096, count=2), 'over the limit of 16777216 pixels'),  # before any is read
        ([('mono8', 4, 4, 4, b'short')], 'frame holds 5 bytes, its header says 4 x 4 = 16'),
    ],
)
def test_frames_that_cannot_be_one_stack_are_refused_saying_why(frames, message):
    with pytest.raises(FrameError, match=re.escape(message)):
        camera_frames.stack_array(frames)
