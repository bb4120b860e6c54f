"""What a key_file costs one request for advice: the learner signs it, the expert checks it and
signs its answer, the learner checks the answer (nodes/advise_msgs.py over core/data/signing.py).

    .venv/bin/python benchmarks/bench_signing.py
    .venv/bin/python benchmarks/bench_signing.py --repeats 5000

Rows: a Pendulum request (no frames), and a camera learner's (84×84 RGB, a stack of 3 frames, as
Advise.srv carries them). Each figure is the median over ``--rounds`` of the mean of ``--repeats``
calls, in microseconds, with all four together beside the request's own serialization (what rclpy
does to send it anyway) for scale. No target, no exit code: a reading.
"""

from __future__ import annotations

import argparse
import statistics
import timeit

from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image

from eqhrl_interfaces.srv import Advise
from eqhrl_ros.core.data.signing import Signer
from eqhrl_ros.nodes import advise_msgs


def request(frames: int) -> Advise.Request:
    frame = Image(height=84, width=84, encoding='rgb8', step=84 * 3, data=bytes(84 * 84 * 3))
    return Advise.Request(
        observation=[1.0, 0.0, 0.0],
        proposed_action=[0.0],
        action_low=[-2.0],
        action_high=[2.0],
        entropy=float('nan'),  # QASAC's
        frames=[frame] * frames,
    )


def micros(call, repeats: int, rounds: int) -> float:
    return statistics.median(timeit.repeat(call, number=repeats, repeat=rounds)) / repeats * 1e6


def row(msg: Advise.Request, key: Signer, repeats: int, rounds: int) -> list:
    """Microseconds of each of the four steps for ``msg``, then their sum, then its serialization."""
    seal = advise_msgs.request_seal(key)
    answer = Advise.Response(advised=True, action=[0.5], expert_name='/expert')
    advise_msgs.sign_request(msg, seal)

    def check_fresh():  # a check of its own each time: the same request twice would be a replay
        advise_msgs.unsigned_request(msg, Advise.Response(), advise_msgs.request_check(key), '/expert', None)

    times = [
        micros(lambda: advise_msgs.sign_request(msg, seal), repeats, rounds),
        micros(check_fresh, repeats, rounds),
        micros(lambda: advise_msgs.sign_answer(answer, msg, advise_msgs.request_check(key)), repeats, rounds),
        micros(lambda: advise_msgs.answer_refusal(answer, msg, seal), repeats, rounds),
    ]
    return [*times, sum(times), micros(lambda: serialize_message(msg), repeats, rounds)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=2000)
    parser.add_argument('--rounds', type=int, default=5)
    args = parser.parse_args()
    key = Signer(b'a deployment key of 32 bytes....')
    print('| request | learner signs | expert checks | expert signs answer | learner checks answer | all four '
          '| serialize (rclpy) |')  # fmt: skip
    print('|---|---|---|---|---|---|---|')
    for name, frames in (('Pendulum', 0), ('camera 84x84 RGB, stack 3', 3)):
        cells = ' | '.join(f'{t:.1f} µs' for t in row(request(frames), key, args.repeats, args.rounds))
        print(f'| {name} | {cells} |')


if __name__ == '__main__':
    main()
