"""Checkpoints on disk: a learner saved to resume, with its replay memories (file I/O in torch_files.py).

Files are torch's zip format, read with ``torch.load(weights_only=True)``: only
tensors and plain Python containers are ever unpickled, so a malicious file
cannot run code. Before that, the zip's directory is checked: torch never
compresses, so a compressed entry (a deflate bomb) is refused, and a file larger
than the learner's sizes can need is refused before it is read, so reading a
file costs at most what the learner's own sizes need.

Writes: the whole file is serialized in memory, written to a temporary file beside
the target with plain ``os.write`` (so a full disk or a read-only folder is an
``OSError`` that names itself), flushed to disk and renamed into place. A failed
write leaves the previous file as it was. The checkpoint and the replay memories
carry the same pairing token, so a resume never combines files of two saves. The two
renames of a save cannot be one: while they happen, the previous replay file stays under
a second name (``.replay.pt.previous``, a hard link), so a save killed between them
resumes from the previous pair instead of losing the replay memories.
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path

import torch

from ..data.errors import CheckpointError
from .records import previous_replay_path
from ..data.torch_files import FORMAT_VERSION, check_zip, not_a_file, replace_file, safe_load, write_temporary

CHECKPOINT_FORMAT = 'eqhrl_ros.checkpoint'
REPLAY_FORMAT = 'eqhrl_ros.replay'


# Room for what a file holds besides its tensors (pickled structure, RNG states, queues, zip records).
_OVERHEAD_BYTES = 4 << 20


def _parameter_count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def checkpoint_size_limit(learner) -> int:
    """The most bytes a checkpoint of this learner can hold: the actor with its two Adam
    moments, the critics and their target copy with theirs, in float32, plus overhead."""
    actor, critic = _parameter_count(learner.actor), _parameter_count(learner.critic)
    encoder = learner.observation.encoder
    encoder_count = 0 if encoder is None else _parameter_count(encoder)
    return 4 * (3 * actor + 4 * critic + 3 * encoder_count) * 2 + _OVERHEAD_BYTES


def replay_size_limit(learner) -> int:
    """The most bytes saved replay memories can hold: both memories full."""
    buffers = (learner.replay, learner.advice_replay)
    return sum(b.saved_bytes_limit() for b in buffers) * 2 + _OVERHEAD_BYTES


def save_checkpoint(learner, path, replay_path=None, extra: dict | None = None) -> None:
    """Save everything needed to resume; the replay memories optionally, to their own file.

    ``extra``: plain values (JSON) saved with the learner and returned by load_checkpoint(),
    for a caller's own state that must stay in step with the learner's (resume_point.py).
    Both files are written in full before either is renamed into place, and both carry
    one pairing token. Raises CheckpointWriteError (the previous files intact) when a
    write fails.
    """
    path = Path(path)
    pair = secrets.token_hex(8)
    written = []
    try:
        if replay_path is not None:
            replay_path = Path(replay_path)
            written.append(
                (
                    write_temporary(
                        {
                            'format': REPLAY_FORMAT,
                            'version': FORMAT_VERSION,
                            'pair': pair,
                            'replay': learner.replay.state_dict(),
                            'advice_replay': learner.advice_replay.state_dict(),
                        },
                        replay_path,
                    ),
                    replay_path,
                )
            )
        written.append(
            (
                write_temporary(
                    {
                        'format': CHECKPOINT_FORMAT,
                        'version': FORMAT_VERSION,
                        'pair': pair,
                        **learner.state_dict(),
                        **({'extra': json.dumps(extra)} if extra is not None else {}),
                    },
                    path,
                ),
                path,
            )
        )
    except BaseException:
        for tmp, _ in written:
            Path(tmp).unlink(missing_ok=True)
        raise
    previous = _keep_previous(replay_path) if replay_path is not None else None
    for tmp, target in written:  # the replay first, then the checkpoint that names it
        replace_file(tmp, target)
    if previous is not None:
        previous.unlink(missing_ok=True)  # the new pair is in place


def _keep_previous(replay_path: Path) -> Path | None:
    """A second name for the replay file about to be replaced (a hard link: no copy), so that
    a save killed between its two renames leaves the previous pair whole. None where there
    is no previous file or the filesystem has no hard links (then such a kill costs the
    replay memories, and the resume says so)."""
    previous = previous_replay_path(replay_path)
    previous.unlink(missing_ok=True)  # left by a save killed before it could remove it
    if not replay_path.exists():
        return None
    try:
        os.link(replay_path, previous)
    except OSError:
        return None
    return previous


def _restore_previous(previous: Path, replay_path: Path) -> None:
    """Put the replay file that pairs with the checkpoint back under its name, so that the
    next save keeps it as its previous one."""
    try:
        os.replace(previous, replay_path)
    except OSError:
        pass  # a folder that cannot be written: the memories are loaded; the next save fails loudly


def check_checkpoint_file(path) -> None:
    """Refuse at once, without unpickling, a checkpoint that is missing or not one (before a
    learner exists to load it into: a node still waiting for the env's spaces)."""
    path = Path(path)
    if not_a_file(path):
        raise CheckpointError(not_a_file(path))
    check_zip(path, CHECKPOINT_FORMAT, None)


def load_checkpoint(learner, path, replay_path=None, check_extra=None) -> dict | None:
    """Restore a learner; returns the ``extra`` saved with it (None if none). Raises
    CheckpointError and leaves the learner unchanged on any problem. ``check_extra(extra)``,
    called before anything changes, may refuse the file by raising CheckpointError."""
    state = safe_load(path, CHECKPOINT_FORMAT, checkpoint_size_limit(learner))
    replay, from_previous = None, False
    if replay_path is not None and Path(replay_path).exists():
        replay = safe_load(replay_path, REPLAY_FORMAT, replay_size_limit(learner))
        previous = previous_replay_path(replay_path)
        if replay.get('pair') != state.get('pair') and previous.exists():
            # A save killed between its two renames: the new replay file, the previous checkpoint.
            replay, from_previous = safe_load(previous, REPLAY_FORMAT, replay_size_limit(learner)), True
        if replay.get('pair') != state.get('pair'):
            raise CheckpointError(
                f'{replay_path} and {path} come from different saves (one was interrupted between '
                f'the two): remove {Path(replay_path).name} to resume without the replay memories'
            )
    # Load into copies first, so that a replay memory that does not fit changes nothing.
    candidate_replay = candidate_advice = None
    if replay is not None:
        try:
            candidate_replay, candidate_advice = (b.empty() for b in (learner.replay, learner.advice_replay))
            candidate_replay.load_state_dict(replay['replay'])
            candidate_advice.load_state_dict(replay['advice_replay'])
        except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
            raise CheckpointError(f'{replay_path}: does not fit this learner ({error})') from error
    try:
        extra = json.loads(state['extra']) if 'extra' in state else None
    except (TypeError, ValueError, RecursionError) as error:  # RecursionError: nested deeper than json reads
        raise CheckpointError(f'{path}: its extra state is not JSON ({error})') from error
    if check_extra is not None:
        check_extra(extra)
    try:
        learner.load_state_dict(state)
    except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
        raise CheckpointError(f'{path}: does not fit this learner ({error})') from error
    if replay is not None:
        learner.memories.replay, learner.memories.advice_replay = candidate_replay, candidate_advice
    if from_previous:
        _restore_previous(previous, Path(replay_path))
    return extra
