"""What an acting node (learner or actor) reports on /diagnostics: the expert, the env, the budget
(and the camera, where it reads one)."""

from __future__ import annotations

import itertools
import time

import numpy as np

from .health import OK, WARN, Check


def acting_checks(node) -> list:
    """The three checks of an ActingNode whose learner exists (nodes/health.py shows them)."""
    learner = node.learner
    with node._lock:
        done, current = learner.advice_total, learner.episode_advice
        asked, given = done.asked + current.asked, done.given + current.given
        timeouts = done.failed['timeout'] + current.failed['timeout']
        untrusted = done.failed['untrusted'] + current.failed['untrusted']
        declined = done.declined + current.declined
        recent = list(itertools.islice(reversed(node.advice.latencies), 1000))  # the last 1,000 answers
        stalled = node.tracking.stalled_since
        window = learner.advice_window()
    servers = node.advice.servers()
    p50, p99 = (f'{v:.0f}' for v in np.percentile(np.asarray(recent) * 1000, (50, 99))) if recent else ('-', '-')
    values = {
        'advise servers': servers,
        'asked': asked,
        'given': given,
        'declined': declined,
        'timeouts': timeouts,
        'untrusted': untrusted,
        'answer latency p50 ms (last 1,000)': p50,
        'answer latency p99 ms (last 1,000)': p99,
    }
    if not window.open:
        expert = Check('expert', OK, f'not asking: {window.why_closed}', values)
    elif not node.params['advice_enabled']:
        expert = Check('expert', OK, 'advice paused (advice_enabled false)', values)
    elif servers == 0:
        expert = Check('expert', WARN, "no node serves 'advise': the learner acts alone", values)
    elif node.advice.serving():
        expert = Check('expert', WARN, f"{servers} nodes serve 'advise': no answer is taken until one does", values)
    elif asked >= 10 and timeouts > asked / 2:
        expert = Check('expert', WARN, f'{timeouts} of {asked} requests timed out', values)
    elif asked >= 10 and untrusted > asked / 2:  # e.g. a key_file here and none on the expert
        expert = Check(
            'expert',
            WARN,
            f'{untrusted} of {asked} answers were not taken (untrusted: not signed with key_file, or not from '
            'accept_expert)',
            values,
        )
    else:
        expert = Check('expert', OK, f'{servers} expert(s) reachable', values)
    if node.tracking.stopped_since is not None:
        env = Check('env', WARN, f'STOPPED by the person for {time.monotonic() - node.tracking.stopped_since:.1f} s')
    elif stalled is not None:
        env = Check('env', WARN, f'no observation for {time.monotonic() - stalled:.1f} s (paused, stopped or starved)')
    else:
        env = Check('env', OK, 'observations arrive')
    env.values = {'steps': learner.total_steps, 'episode': learner.episode, 'stalls': node.stalls}
    seconds = window.seconds_left
    budget = Check(
        'budget',
        OK,
        f'{window.episodes_left} episodes of advice left'
        + (f", {seconds:.0f} s of the person's" if seconds < float('inf') else ''),
        {'episodes left': window.episodes_left, 'person seconds spent': f'{learner.human_time_total_s:.1f}'},
    )
    camera = [] if node.camera_input is None else [node.camera_input.health_check()]
    return [expert, env, budget, *camera]
