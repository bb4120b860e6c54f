"""Every conversion between the Advise service (eqhrl_interfaces/srv/Advise.srv) and the core's
AdviceRequest and Advice, in one place: the learner sends and reads, experts read and answer."""

from __future__ import annotations

import math
import struct
from dataclasses import replace
from typing import Optional

import numpy as np

from eqhrl_interfaces.srv import Advise

from ..core.data.advice import Advice, AdviceRequest
from ..core.data.camera_frames import FrameError
from ..core.data.signing import SIGNATURE_BYTES, RequestCheck, RequestSeal
from .frame_msgs import stack_msgs, stack_of
from .messages import REASON_MAX, printable_text


def request_msg(request: AdviceRequest, timeout_s: float = 0.0) -> Advise.Request:
    """The learner's request as the service carries it; ``timeout_s``: how long it waits."""
    return Advise.Request(
        timeout_s=float(timeout_s),
        observation=request.observation.tolist(),
        proposed_action=request.proposed_action.tolist(),
        action_low=request.action_low.tolist(),
        action_high=request.action_high.tolist(),
        discrepancy=float(request.discrepancy),
        entropy=float(request.entropy),
        episode=int(request.episode),
        step=int(request.step),
        frames=stack_msgs(request.pixels),
    )


def request_refusal(msg: Advise.Request) -> str:
    """'' when a request can be answered, by what every expert needs of it: finite values and
    action bounds with low < high in every dimension (an answer clipped to upside-down bounds, or
    made from NaN ones, would be no action at all); else why not, for the expert's decline."""
    low, high = list(msg.action_low), list(msg.action_high)
    if len(low) != len(high):
        return f'action_low has {len(low)} values, action_high {len(high)}'
    if not all(math.isfinite(v) for v in (*msg.observation, *low, *high)):
        return 'the observation or the action bounds hold a non-finite value'
    if any(lo >= hi for lo, hi in zip(low, high)):
        return f'action bounds need low < high in every dimension: low {low}, high {high}'
    return ''


def request_from_msg(msg: Advise.Request) -> AdviceRequest:
    """What an expert is asked, as the core's AdviceRequest; frames that cannot be one stack
    raise camera_frames.FrameError (frame_msgs.stack_of)."""

    def arr(values):
        return np.asarray(values, dtype=np.float32)

    return AdviceRequest(
        arr(msg.observation),
        arr(msg.proposed_action),
        arr(msg.action_low),
        arr(msg.action_high),
        float(msg.discrepancy),
        float(msg.entropy),
        int(msg.episode),
        int(msg.step),
        stack_of(msg.frames),
    )


def answer(expert, msg: Advise.Request, response: Advise.Response, name: str, logger) -> Advise.Response:
    """Ask ``expert`` (a core Expert callable) and fill ``response``. A backend that raises
    declines this one request with the error as its reason; the service lives on."""
    try:
        request = request_from_msg(msg)
    except FrameError as error:
        return fill_response(response, frames_refused(error, logger), name)
    try:
        advice = expert(request)
    except Exception as error:  # a backend bug must not take the service down
        logger.error(f'expert backend failed: {error!r}', throttle_duration_sec=5.0)
        advice = Advice.decline(f'expert error: {error}')
    return fill_response(response, advice, name)


def frames_refused(error: FrameError, logger) -> Advice:
    """A request whose frames cannot be one stack (another node's bytes): declined, saying why,
    and said in the log; the service lives on."""
    logger.warning(f'a request with frames refused: {error}', throttle_duration_sec=5.0)
    return Advice.decline(f'frames refused: {error}')


def fill_response(response: Advise.Response, advice: Advice, name: str) -> Advise.Response:
    response.expert_name = name
    response.advised = advice.advised
    response.human = bool(advice.human)
    response.response_time_s = float(advice.response_time_s)
    response.timed_out = bool(advice.timed_out)
    if advice.advised:
        response.action = np.asarray(advice.action, dtype=np.float32).tolist()
    else:
        response.reason = advice.reason or 'declined'
    return response


def advice_from_response(response: Advise.Response, name: str) -> Advice:
    """The answer as the core's Advice; ``name`` is the expert's name as the learner shows it. The
    reason is another node's text, bound for learner/advice_request and the person's page and terminal: one
    printable line of at most REASON_MAX characters."""
    action = np.asarray(response.action, dtype=np.float32) if response.advised else None
    reason = printable_text(response.reason, REASON_MAX)
    return Advice(action, reason, name, bool(response.human), float(response.response_time_s), bool(response.timed_out))


def person_time_checked(advice: Advice, waited_s: float) -> tuple[Advice, bool]:
    """``advice`` with a person's time the learner can believe, and whether it had to be changed.
    The expert measures from the request's arrival to its answer, inside the learner's own wait
    (``waited_s``, from sending to the answer): a time that is not a number from 0 to that wait is
    taken as the wait. Otherwise an expert's word of 10^6 s would spend the person's seconds, and
    a NaN would reach the person's page."""
    claim = advice.response_time_s
    if not advice.human or 0.0 <= claim <= waited_s:
        return advice, False
    return replace(advice, response_time_s=float(waited_s)), True


# Signed with key_file (core/data/signing.py): the parts each signature covers, field by field.
SIGNED_KIND = 'advise'


def _f32(values) -> bytes:
    """float32 values as bytes, each NaN as the one NaN (QASAC's entropy): a NaN's bits may differ
    between the learner's value and the one the expert reads, and the signature must not."""
    values = np.asarray(values, dtype='<f4').reshape(-1)
    return np.where(np.isnan(values), np.float32('nan'), values).astype('<f4').tobytes()


def _text(text: str) -> bytes:
    """Another node's text as bytes, whatever it holds (a lone surrogate must not raise in a callback)."""
    return text.encode('utf-8', 'surrogatepass')


def request_parts(msg: Advise.Request) -> list:
    """The request's content, as its signature covers it (everything but counter and signature)."""
    parts = [
        _f32(msg.observation),
        _f32(msg.proposed_action),
        _f32(msg.action_low),
        _f32(msg.action_high),
        _f32([msg.discrepancy, msg.entropy, msg.timeout_s]),
        struct.pack('<ii', msg.episode, msg.step),
    ]
    for frame in msg.frames:
        header = struct.pack('<iIIII?', frame.header.stamp.sec, frame.header.stamp.nanosec, frame.height,
                             frame.width, frame.step, bool(frame.is_bigendian))  # fmt: skip
        parts += [header, _text(frame.header.frame_id), _text(frame.encoding), bytes(frame.data)]
    return parts


def answer_parts(msg: Advise.Response) -> list:
    """The answer's content, as its signature covers it (everything but the signature)."""
    flags = struct.pack('<???', bool(msg.advised), bool(msg.human), bool(msg.timed_out))
    return [flags, _f32(msg.action), _f32([msg.response_time_s]), _text(msg.reason), _text(msg.expert_name)]


def request_seal(signer) -> Optional[RequestSeal]:
    """The learner's seal of its requests with key_file's signer; None: unsigned."""
    return RequestSeal(signer, SIGNED_KIND) if signer else None


def request_check(signer) -> Optional[RequestCheck]:
    """An expert's check of requests with key_file's signer; None: any well-formed request is taken."""
    return RequestCheck(signer, SIGNED_KIND) if signer else None


def sign_request(msg: Advise.Request, seal: Optional[RequestSeal]) -> Advise.Request:
    if seal is not None:
        msg.counter, signature = seal.seal(request_parts(msg))
        msg.signature = list(signature)
    return msg


def answer_refusal(msg: Advise.Response, request: Advise.Request, seal: Optional[RequestSeal]) -> str:
    """'' when the learner may take this answer to ``request``: no key is set, or it is signed for it."""
    if seal is None:
        return ''
    return seal.answer_refusal(request.counter, bytes(request.signature), answer_parts(msg), bytes(msg.signature))


def unsigned_request(
    msg: Advise.Request, response: Advise.Response, check: Optional[RequestCheck], name: str, logger
) -> Optional[Advise.Response]:
    """An expert's decline (itself unsigned) of a request its key_file does not vouch for, said in
    its log; None when the request may be answered (it is then marked as taken: a copy of it is
    refused as a replay)."""
    if check is None:
        return None
    signature = bytes(msg.signature)
    # A stranger's request is not hashed (its frames may be large): only one that may be signed.
    parts = request_parts(msg) if msg.counter and len(signature) == SIGNATURE_BYTES else []
    refusal = check.refusal(msg.counter, parts, signature)
    if not refusal:
        return None
    reason = f'request refused: {refusal}'
    logger.warning(f'{reason} (episode {msg.episode}, step {msg.step})', throttle_duration_sec=5.0)
    return fill_response(response, Advice.decline(reason), name)


def sign_answer(msg: Advise.Response, request: Advise.Request, check: Optional[RequestCheck]) -> Advise.Response:
    """The expert's answer, signed for ``request`` when it has a key (only answers to requests it took)."""
    if check is not None:
        msg.signature = list(check.seal_answer(request.counter, bytes(request.signature), answer_parts(msg)))
    return msg
