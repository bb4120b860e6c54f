"""What advice_console shows of the learner's messages, each checked by meaning first.

The page is a person's view of the run. A number out of meaning there (a NaN wait, an infinite
return, an action of another size than the env's) would mislead them at best; and JSON has no
NaN, so before these checks one such number froze the page: its parser refused every state that
held the message, and the console keeps the latched request and 500 episodes. A message out of
meaning is dropped (the node says so in its log) and the page keeps showing the one before.
"""

from __future__ import annotations

import math
from typing import Optional

from rclpy.parameter import parameter_value_to_python

from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats

from ..parameters import check_section
from .messages import OUTCOME_NAMES, REASON_MAX, printable_text

STATS_SECONDS = ('human_time_s', 'human_time_total_s', 'takeover_s')
STATS_COUNTS = ('length', 'advice_asked', 'advice_given', 'advice_human', 'takeover_steps', 'asked_steps')


def request_shown(msg: AdviceRequest, action_size: Optional[int]) -> dict:
    """The page's fields of an AdviceRequest; ValueError says what is out of meaning in it.
    ``action_size``: the env's, once known (an action of another size is not this env's)."""
    if msg.outcome not in OUTCOME_NAMES:
        raise ValueError(f'outcome {msg.outcome} is none of {sorted(OUTCOME_NAMES)}')
    for name in ('timeout_s', 'response_time_s'):
        _seconds(name, getattr(msg, name))
    if msg.steps_driven < 0:
        raise ValueError(f'steps_driven {msg.steps_driven} < 0')
    for name in ('proposed_action', 'given_action'):  # empty: none (a stand-in, a declined request)
        values = getattr(msg, name)
        if action_size is not None and len(values) not in (0, action_size):
            raise ValueError(f'{name} has {len(values)} values; the env acts with {action_size}')
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'{name} holds a value that is not finite')
    # An expert's reason or a failure's kind: a line, not a document, as the learner cuts it (a node
    # posing as the learner cuts nothing).
    detail = printable_text(msg.detail, REASON_MAX)
    return {
        'outcome': OUTCOME_NAMES[msg.outcome],
        'detail': detail,
        'episode': msg.episode,
        'step': msg.step,
        'discrepancy': finite_or_none(msg.discrepancy),
        'entropy': finite_or_none(msg.entropy),  # NaN in QASAC: shown as n/a
        'timeout_s': float(msg.timeout_s),
        'human': bool(msg.human),
        'response_time_s': float(msg.response_time_s),
        'proposed_action': [float(v) for v in msg.proposed_action],
        'given_action': [float(v) for v in msg.given_action],
        'wheel': bool(msg.wheel),
        'steps_driven': int(msg.steps_driven),
    }


def stats_shown(msg: EpisodeStats) -> dict:
    """The page's fields of an episode's statistics; ValueError says what is out of meaning."""
    if not math.isfinite(msg.episode_return):
        raise ValueError(f'episode_return {msg.episode_return} is not finite')
    for name in STATS_SECONDS:
        _seconds(name, getattr(msg, name))
    for name in ('episode', *STATS_COUNTS):
        if getattr(msg, name) < 0:
            raise ValueError(f'{name} {getattr(msg, name)} < 0')
    return {
        'episode': msg.episode,
        'return': float(msg.episode_return),
        'asked': msg.advice_asked,
        'given': msg.advice_given,
        'human': msg.advice_human,
        'human_time_s': float(msg.human_time_s),
        'human_time_total_s': float(msg.human_time_total_s),
        'success': bool(msg.success),
        'takeover_steps': msg.takeover_steps,
        'takeover_s': float(msg.takeover_s),
        'asked_steps': msg.asked_steps,
    }


def finite_or_none(value: float) -> Optional[float]:
    return float(value) if math.isfinite(value) else None  # JSON has no NaN


def _seconds(name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f'{name} {value} is not a finite number of seconds >= 0')


def parameters_shown(future, names, node_name: str, tables, node) -> dict:
    """A get_parameters answer as {name: value} (arrays as lists), those set alone, each checked as
    that node checks it (type, range, choices: ``tables``); {} when the node went away meanwhile, or
    when a value is not one it could hold (a stranger posing as it while it is not running: before,
    a string where the page needs a number broke the page's drawing), said in the log."""
    try:
        values = future.result().values
    except Exception:
        return {}
    read = {name: parameter_value_to_python(value) for name, value in zip(names, values)}
    read = {
        name: list(v) if not isinstance(v, (bool, int, float, str)) else v for name, v in read.items() if v is not None
    }
    try:
        check_section(node_name, read, *tables)
    except ValueError as why:
        node.get_logger().warning(f'not shown on the page: {why}', throttle_duration_sec=10.0)
        return {}
    return read
