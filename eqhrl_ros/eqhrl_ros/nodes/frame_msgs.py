"""sensor_msgs/Image to and from pixels, in one place: the env's camera, the frames a request
asks about (Advise.srv and AdviceRequest.msg ``frames``) and the person's page read and build
them here, through core/data/camera_frames.py's checks by meaning."""

from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np
from sensor_msgs.msg import CompressedImage, Image

from ..core.data import camera_frames
from ..core.envs.spec import EnvCamera


def image_msg(frame: np.ndarray, frame_id: str, stamp=None) -> Image:
    """A uint8 (H, W, C) frame, RGB or mono, as a raw Image (rgb8 or mono8)."""
    encoding, height, width, step, data = camera_frames.frame_fields(frame)
    msg = Image(height=height, width=width, encoding=encoding, is_bigendian=0, step=step, data=data)
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def frame_of(msg: Image, max_pixels: int = camera_frames.MAX_FRAME_PIXELS) -> np.ndarray:
    """A raw Image's pixels, uint8 (H, W, C), or camera_frames.FrameError saying why not."""
    return camera_frames.frame_array(msg.encoding, msg.height, msg.width, msg.step, msg.data, max_pixels)


def announced_frame(msg: Union[Image, CompressedImage], camera: EnvCamera) -> np.ndarray:
    """A camera's frame, raw or compressed (JPEG or PNG), as uint8 (H, W, C), checked against what
    env_info announced: a raw frame's encoding and size before its bytes are read; a compressed
    one's declared size before it is decoded (no more pixels than announced: a frame that would
    decode to gigabytes costs nothing), then what it decodes to. camera_frames.FrameError if not."""
    if isinstance(msg, CompressedImage):
        frame = camera_frames.decode_compressed(msg.data, max_pixels=camera.height * camera.width)
        if frame.shape != (camera.height, camera.width, camera.channels):
            raise camera_frames.FrameError(
                f'a frame that decodes to {frame.shape[1]}x{frame.shape[0]}x{frame.shape[2]}, the env announced '
                f'{camera.width}x{camera.height}x{camera.channels}'
            )
        return frame
    if msg.encoding != camera.encoding or (msg.height, msg.width) != (camera.height, camera.width):
        raise camera_frames.FrameError(
            f'a {msg.width}x{msg.height} {msg.encoding!r} frame, the env announced '
            f'{camera.width}x{camera.height} {camera.encoding}'
        )
    return frame_of(msg)


def stack_msgs(pixels: Optional[np.ndarray]) -> list[Image]:
    """A stack uint8 [k, H, W, C] (oldest first) as k Images, their headers empty (a request's
    frames); none for None (no camera)."""
    return [] if pixels is None else [image_msg(frame, '') for frame in pixels]


def stack_of(msgs: Sequence[Image]) -> Optional[np.ndarray]:
    """Images (oldest first) as one stack uint8 [k, H, W, C]; None for none. Frames from another
    node are checked before anything is copied (camera_frames.stack_array): FrameError if they
    cannot be one stack."""
    if not msgs:
        return None
    return camera_frames.stack_array((m.encoding, m.height, m.width, m.step, m.data) for m in msgs)
