"""Camera frames as arrays, checked by meaning: the one home of how a raw image's fields become
pixels, and of decoding a compressed frame without trusting it (issue 49, items 1 and 5).

The fields are those of sensor_msgs/Image (encoding, height, width, step, data) and of
sensor_msgs/CompressedImage (format, data); the nodes pass them in, so the core imports no ROS.
A frame comes out as uint8 (H, W, C): RGB for colour (bgr8 is turned round), C = 1 for mono8.
What does not fit raises FrameError, saying what was wrong; nothing is guessed.
"""

from __future__ import annotations

import io

import numpy as np

# The raw encodings a frame may come in (sensor_msgs/image_encodings names) and their channels.
ENCODINGS = {'rgb8': 3, 'bgr8': 3, 'mono8': 1}
# Largest frame accepted, raw or decoded: 4096 x 4096 pixels (48 MiB of RGB). A header that
# declares more is refused before anything is allocated or decoded.
MAX_FRAME_PIXELS = 4096 * 4096
# Most frames a learner stacks (CameraSpec.stack), and so most a request carries.
MAX_FRAME_STACK = 16
# Channels -> the raw encoding a frame is sent in (what frame_array reads back).
SENT_ENCODINGS = {3: 'rgb8', 1: 'mono8'}


class FrameError(ValueError):
    """A frame that cannot be taken as it is: the message says why."""


def _check_size(height: int, width: int, max_pixels: int) -> None:
    if height < 1 or width < 1:
        raise FrameError(f'frame of {width}x{height} pixels is empty')
    if height * width > max_pixels:
        raise FrameError(f'frame of {width}x{height} pixels is over the limit of {max_pixels} pixels')


def frame_array(encoding: str, height: int, width: int, step: int, data, max_pixels: int = MAX_FRAME_PIXELS):
    """A raw frame's pixels as uint8 (H, W, C), RGB or mono; rows of ``step`` bytes may be padded."""
    channels = ENCODINGS.get(encoding)
    if channels is None:
        raise FrameError(f'frame encoding {encoding!r} is not one of {", ".join(ENCODINGS)}')
    _check_size(height, width, max_pixels)
    if step < width * channels:
        raise FrameError(f'frame step {step} is shorter than a row of {width} {encoding} pixels ({width * channels})')
    pixels = np.frombuffer(bytes(data), np.uint8)
    if pixels.size != step * height:
        raise FrameError(f'frame holds {pixels.size} bytes, its header says {step} x {height} = {step * height}')
    array = pixels.reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    return array[:, :, ::-1].copy() if encoding == 'bgr8' else array


def frame_fields(frame: np.ndarray) -> tuple[str, int, int, int, bytes]:
    """(encoding, height, width, step, data) of a uint8 (H, W, C) frame, RGB or mono: the raw
    fields frame_array reads back."""
    frame = np.ascontiguousarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] not in SENT_ENCODINGS:
        raise FrameError(f'a frame to send is uint8 (H, W, 1 or 3), got {frame.dtype} {frame.shape}')
    height, width, channels = frame.shape
    return SENT_ENCODINGS[channels], height, width, width * channels, frame.tobytes()


def stack_array(frames, max_pixels: int = MAX_FRAME_PIXELS) -> np.ndarray:
    """Raw frames, each (encoding, height, width, step, data), oldest first, as one stack uint8
    [k, H, W, C]: at most MAX_FRAME_STACK frames of one size and encoding, ``max_pixels`` in
    all, each checked by frame_array before anything is copied."""
    frames = list(frames)
    if not 1 <= len(frames) <= MAX_FRAME_STACK:
        raise FrameError(f'a stack holds 1 to {MAX_FRAME_STACK} frames, got {len(frames)}')
    kinds = {(encoding, height, width) for encoding, height, width, _, _ in frames}
    if len(kinds) > 1:
        raise FrameError(f'the frames of a stack differ in encoding or size: {sorted(kinds)}')
    _, height, width = kinds.pop()
    _check_size(height * len(frames), width, max_pixels)
    return np.stack([frame_array(e, h, w, s, data, max_pixels=max_pixels) for e, h, w, s, data in frames])


def decode_compressed(data, max_pixels: int = MAX_FRAME_PIXELS) -> np.ndarray:
    """A compressed frame (JPEG or PNG, as sensor_msgs/CompressedImage carries it) as uint8
    (H, W, C), RGB or mono. Its declared size is checked before it is decoded, so a frame that
    would decode to gigabytes costs nothing; one that does not decode raises FrameError."""
    from PIL import Image, UnidentifiedImageError

    try:
        image = Image.open(io.BytesIO(bytes(data)))  # reads the header only
    except Image.DecompressionBombError as error:  # pillow's own guard, far above ours
        raise FrameError(f'compressed frame is over the limit of {max_pixels} pixels: {error}') from None
    except (UnidentifiedImageError, OSError) as error:
        raise FrameError(f'compressed frame does not decode: {error}') from None
    if image.format not in ('JPEG', 'PNG'):
        raise FrameError(f'compressed frame is {image.format}, not JPEG or PNG')
    width, height = image.size
    _check_size(height, width, max_pixels)
    try:
        pixels = image.convert('L' if image.mode in ('L', '1', 'I;16') else 'RGB')
    except (OSError, ValueError, SyntaxError) as error:  # truncated or corrupt data past the header
        raise FrameError(f'compressed frame does not decode: {error}') from None
    array = np.asarray(pixels, dtype=np.uint8)
    return array[:, :, None] if array.ndim == 2 else array


def png_bytes(frames: np.ndarray) -> bytes:
    """A stack uint8 [k, H, W, C] as one PNG, its frames side by side, oldest left: lossless, so a
    person sees each pixel the learner reads."""
    from PIL import Image

    k, height, width, channels = frames.shape
    row = frames.transpose(1, 0, 2, 3).reshape(height, k * width, channels)
    out = io.BytesIO()
    Image.fromarray(row[:, :, 0] if channels == 1 else row).save(out, format='PNG')
    return out.getvalue()


def jpeg_bytes(frame: np.ndarray, quality: int) -> bytes:
    """A uint8 (H, W, C) frame, RGB or mono, as JPEG bytes."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(frame[:, :, 0] if frame.shape[2] == 1 else frame).save(out, format='JPEG', quality=quality)
    return out.getvalue()
