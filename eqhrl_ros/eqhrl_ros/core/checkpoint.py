"""Checkpoints and exported policies on disk.

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

import io
import json
import os
import pickle
import secrets
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import torch

from .env_spec import ActionScaler
from .errors import CheckpointError, CheckpointWriteError
from .experts import Advice, AdviceRequest
from .networks import SquashedGaussianActor
from .records import previous_replay_path

CHECKPOINT_FORMAT = 'eqhrl_ros.checkpoint'
REPLAY_FORMAT = 'eqhrl_ros.replay'
POLICY_FORMAT = 'eqhrl_ros.policy'
FORMAT_VERSION = 1


def _write_file(data: bytes, tmp: str) -> None:
    fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_temporary(obj: dict, path: Path) -> str:
    """Serialize ``obj`` and write it to a temporary file beside ``path``; returns its name."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    except OSError as error:
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error
    os.close(fd)
    try:
        _write_file(buffer.getbuffer(), tmp)
    except OSError as error:
        Path(tmp).unlink(missing_ok=True)
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return tmp


def _replace(tmp: str, path: Path) -> None:
    try:
        os.replace(tmp, path)
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself reaches the disk
        finally:
            os.close(dir_fd)
    except OSError as error:
        Path(tmp).unlink(missing_ok=True)
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error


def _atomic_save(obj: dict, path: Path) -> None:
    path = Path(path)
    _replace(_write_temporary(obj, path), path)


def _check_zip(path: Path, expected_format: str, max_bytes: int | None) -> None:
    """Refuse, before unpickling, what torch.save never writes or what is larger than needed."""
    size = path.stat().st_size
    if max_bytes is not None and size > max_bytes:
        raise CheckpointError(f"{path}: {size:,} bytes, more than the {max_bytes:,} that this learner's sizes can need")
    try:
        with zipfile.ZipFile(path) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError) as error:
        raise CheckpointError(f'{path}: not a readable {expected_format} file ({error})') from error
    for entry in entries:
        if entry.compress_type != zipfile.ZIP_STORED:
            raise CheckpointError(
                f'{path}: entry {entry.filename!r} is compressed; torch.save never '
                'compresses, so the file is refused unread'
            )
        if entry.file_size > size:
            raise CheckpointError(
                f'{path}: entry {entry.filename!r} claims {entry.file_size:,} bytes in a file of {size:,}'
            )


def _safe_load(path: Path, expected_format: str, max_bytes: int | None = None) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f'{path}: no such file')
    _check_zip(path, expected_format, max_bytes)
    try:
        obj = torch.load(path, map_location='cpu', weights_only=True)
    except (
        pickle.UnpicklingError,
        RuntimeError,
        EOFError,
        zipfile.BadZipFile,
        ValueError,
        AttributeError,
        TypeError,
        OSError,
    ) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise CheckpointError(f'{path}: not a readable {expected_format} file ({first_line})') from error
    if not isinstance(obj, dict) or obj.get('format') != expected_format:
        found = obj.get('format') if isinstance(obj, dict) else type(obj).__name__
        raise CheckpointError(f'{path}: expected a {expected_format} file, found {found!r}')
    if obj.get('version') != FORMAT_VERSION:
        raise CheckpointError(f'{path}: format version {obj.get("version")!r}, this code reads {FORMAT_VERSION}')
    return obj


# Room for what a file holds besides its tensors (pickled structure, RNG states, queues, zip records).
_OVERHEAD_BYTES = 4 << 20


def _parameter_count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def checkpoint_size_limit(learner) -> int:
    """The most bytes a checkpoint of this learner can hold: the actor with its two Adam
    moments, the critics and their target copy with theirs, in float32, plus overhead."""
    actor, critic = _parameter_count(learner.actor), _parameter_count(learner.critic)
    return 4 * (3 * actor + 4 * critic) * 2 + _OVERHEAD_BYTES


def replay_size_limit(learner) -> int:
    """The most bytes saved replay memories can hold: both memories full, float32 rows."""
    buffers = (learner.replay, learner.advice_replay)
    return sum(4 * b.capacity * b.rows.shape[1] for b in buffers) * 2 + _OVERHEAD_BYTES


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
                    _write_temporary(
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
                _write_temporary(
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
        _replace(tmp, target)
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
    if not path.is_file():
        raise CheckpointError(f'{path}: no such file')
    _check_zip(path, CHECKPOINT_FORMAT, None)


def load_checkpoint(learner, path, replay_path=None, check_extra=None) -> dict | None:
    """Restore a learner; returns the ``extra`` saved with it (None if none). Raises
    CheckpointError and leaves the learner unchanged on any problem. ``check_extra(extra)``,
    called before anything changes, may refuse the file by raising CheckpointError."""
    state = _safe_load(path, CHECKPOINT_FORMAT, checkpoint_size_limit(learner))
    replay, from_previous = None, False
    if replay_path is not None and Path(replay_path).exists():
        replay = _safe_load(replay_path, REPLAY_FORMAT, replay_size_limit(learner))
        previous = previous_replay_path(replay_path)
        if replay.get('pair') != state.get('pair') and previous.exists():
            # A save killed between its two renames: the new replay file, the previous checkpoint.
            replay, from_previous = _safe_load(previous, REPLAY_FORMAT, replay_size_limit(learner)), True
        if replay.get('pair') != state.get('pair'):
            raise CheckpointError(
                f'{replay_path} and {path} come from different saves (one was interrupted between '
                f'the two): remove {Path(replay_path).name} to resume without the replay memories'
            )
    # Load into copies first, so that a replay memory that does not fit changes nothing.
    candidate_replay = candidate_advice = None
    if replay is not None:
        try:
            candidate_replay, candidate_advice = (
                type(b)(b.capacity, b.obs_dim, b.action_dim) for b in (learner.replay, learner.advice_replay)
            )
            candidate_replay.load_state_dict(replay['replay'])
            candidate_advice.load_state_dict(replay['advice_replay'])
        except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
            raise CheckpointError(f'{replay_path}: does not fit this learner ({error})') from error
    try:
        extra = json.loads(state['extra']) if 'extra' in state else None
    except (TypeError, ValueError) as error:
        raise CheckpointError(f'{path}: its extra state is not JSON ({error})') from error
    if check_extra is not None:
        check_extra(extra)
    try:
        learner.load_state_dict(state)
    except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
        raise CheckpointError(f'{path}: does not fit this learner ({error})') from error
    if replay is not None:
        learner.replay, learner.advice_replay = candidate_replay, candidate_advice
    if from_previous:
        _restore_previous(previous, Path(replay_path))
    return extra


def export_policy(learner, path) -> None:
    """A small file with the actor alone: an expert node can serve it (a learner becomes a teacher)."""
    _atomic_save(
        {
            'format': POLICY_FORMAT,
            'version': FORMAT_VERSION,
            'obs_dim': learner.obs_dim,
            'hidden': list(learner.config.hidden),
            'action_low': learner.scaler.low.tolist(),
            'action_high': learner.scaler.high.tolist(),
            'actor': {k: v.cpu() for k, v in learner.actor.state_dict().items()},
        },
        path,
    )


class PolicyExpert:
    """An expert that answers with an exported policy's deterministic action tanh(mean)."""

    def __init__(self, path, name: str = 'policy'):
        data = _safe_load(path, POLICY_FORMAT)
        try:
            self.scaler = ActionScaler(data['action_low'], data['action_high'])
            self.obs_dim = int(data['obs_dim'])
            self.actor = SquashedGaussianActor(self.obs_dim, self.scaler.dim, tuple(data['hidden']))
            self.actor.load_state_dict(data['actor'])
        except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
            raise CheckpointError(f'{path}: broken policy file ({error})') from error
        if not all(torch.isfinite(p).all() for p in self.actor.parameters()):
            raise CheckpointError(f'{path}: the policy holds non-finite weights (NaN or inf)')
        self.actor.eval()
        self.name = name
        self.observation_size, self.action_size = self.obs_dim, self.scaler.dim

    @torch.no_grad()
    def action(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32).reshape(-1)
        if obs.shape[0] != self.obs_dim:
            raise ValueError(f'observation has {obs.shape[0]} values, the policy expects {self.obs_dim}')
        mean, _ = self.actor(torch.from_numpy(obs).unsqueeze(0))
        return self.scaler.to_env(torch.tanh(mean)[0].numpy())

    def __call__(self, request: AdviceRequest) -> Advice:
        return Advice(self.action(request.observation), expert_name=self.name)
