"""What the trainer node says about itself: its /diagnostics checks and its periodic log line."""

from __future__ import annotations

import time

from .health import OK, WARN, Check
from .messages import printable_name


def trainer_checks(node) -> list:
    """The actors and the learning of a TrainerNode, for /diagnostics (nodes/health.py)."""
    trainer = node.trainer
    if trainer is None:
        return [Check('actors', WARN, 'waiting for the first batch (or env_id) to know the spaces')]
    now, limit = time.monotonic(), node.params['actor_silence_s']
    sequences = dict(trainer.sequences.actors)
    silent = sorted(printable_name(a) for a, s in sequences.items() if now - s.last_heard > limit)
    values = {
        'actors': len(sequences),
        'silent': len(silent),
        'batches lost': trainer.sequences.lost,
        'batches refused': node.refused_batches,
        'batches dropped (inbox full)': node.dropped_batches,
    }
    if node.done:  # the run has ended: silence is what it asked for
        actors = Check('actors', OK, 'the run has ended (max_episodes): no batch is stored any more', values)
    elif not sequences:
        actors = Check('actors', WARN, 'no actor has sent transitions yet', values)
    elif silent:
        actors = Check('actors', WARN, f'silent for over {limit:g} s: {", ".join(silent[:5])}', values)
    else:
        actors = Check('actors', OK, f'{len(sequences)} actor(s) sending', values)
    learning = Check(
        'learning',
        WARN if trainer.restored else OK,
        f'networks restored {trainer.restored} times after non-finite updates' if trainer.restored else 'learning',
        {'updates': node.learner.updates, 'weights sent': node.weights_published, 'owed': trainer.updates_owed()},
    )
    return [actors, learning]


def report(node) -> None:
    """The trainer's periodic log line, and a warning once per actor that went silent.

    Without the lock: counters only (ints, read whole); the learning thread keeps going."""
    if node.trainer is None:
        return
    now, transitions, updates = time.monotonic(), node.learner.total_steps, node.learner.updates
    then, before_t, before_u = node.report_mark
    if node.done and (transitions, updates) == (before_t, before_u):
        return  # the run has ended and its last counts are said: the same line every period says nothing
    node.report_mark = (now, transitions, updates)
    seconds = max(now - then, 1e-9)
    sequences = node.trainer.sequences.actors
    node.get_logger().info(
        f'{transitions} transitions from {len(sequences)} actor(s) '
        f'({(transitions - before_t) / seconds:.1f}/s), '
        f'{updates} updates ({(updates - before_u) / seconds:.1f}/s), {node.trainer.updates_owed()} owed, '
        f'weights v{updates} sent {node.weights_published} times, '
        f'{node.trainer.sequences.lost} batches lost, '
        f'{sum(s.out_of_order for s in sequences.values())} held past a gap, '
        f'{sum(s.duplicates for s in sequences.values())} received twice, {node.refused_batches} refused, '
        f'{node.dropped_batches} dropped (inbox full)'
    )
    limit = node.params['actor_silence_s']
    if node.done:  # the run has ended and told its actors to stop: their silence is no news
        return
    for actor, state in list(sequences.items()):
        if actor not in node.silent_actors and now - state.last_heard > limit:
            node.silent_actors.add(actor)
            node.get_logger().warn(
                f'actor {printable_name(actor)} has sent nothing for {now - state.last_heard:.1f} s '
                '(stopped, paused or cut off); the others go on'
            )
