"""Checkpoints and exported policies on disk.

Files are torch's zip format, read with ``torch.load(weights_only=True)``: only
tensors and plain Python containers are ever unpickled, so a malicious file
cannot run code. Writes go to a temporary file first and are renamed into place,
so a crash mid-write never leaves a truncated checkpoint behind.
"""

from __future__ import annotations

import os
import pickle
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import torch

from .envs import ActionScaler
from .experts import Advice, AdviceRequest
from .networks import SquashedGaussianActor

CHECKPOINT_FORMAT = 'eqhrl_ros.checkpoint'
REPLAY_FORMAT = 'eqhrl_ros.replay'
POLICY_FORMAT = 'eqhrl_ros.policy'
FORMAT_VERSION = 1


class CheckpointError(RuntimeError):
    """A checkpoint or policy file that cannot be used: unreadable, not ours, or mismatched."""


def _atomic_save(obj: dict, path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _safe_load(path: Path, expected_format: str) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f'{path}: no such file')
    try:
        obj = torch.load(path, map_location='cpu', weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, ValueError,
            AttributeError, TypeError, OSError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise CheckpointError(f'{path}: not a readable {expected_format} file ({first_line})') from error
    if not isinstance(obj, dict) or obj.get('format') != expected_format:
        found = obj.get('format') if isinstance(obj, dict) else type(obj).__name__
        raise CheckpointError(f'{path}: expected a {expected_format} file, found {found!r}')
    if obj.get('version') != FORMAT_VERSION:
        raise CheckpointError(f"{path}: format version {obj.get('version')!r}, this code reads {FORMAT_VERSION}")
    return obj


def save_checkpoint(learner, path, replay_path=None) -> None:
    """Save everything needed to resume; the replay memories optionally, to their own file."""
    _atomic_save({'format': CHECKPOINT_FORMAT, 'version': FORMAT_VERSION, **learner.state_dict()}, path)
    if replay_path is not None:
        _atomic_save({'format': REPLAY_FORMAT, 'version': FORMAT_VERSION,
                      'replay': learner.replay.state_dict(),
                      'advice_replay': learner.advice_replay.state_dict()}, replay_path)


def load_checkpoint(learner, path, replay_path=None) -> None:
    """Restore a learner. Raises CheckpointError and leaves the learner unchanged on any problem."""
    state = _safe_load(path, CHECKPOINT_FORMAT)
    try:
        learner.load_state_dict(state)
    except (KeyError, ValueError, RuntimeError, TypeError) as error:
        raise CheckpointError(f'{path}: does not fit this learner ({error})') from error
    if replay_path is not None and Path(replay_path).exists():
        replay = _safe_load(replay_path, REPLAY_FORMAT)
        try:
            learner.replay.load_state_dict(replay['replay'])
            learner.advice_replay.load_state_dict(replay['advice_replay'])
        except (KeyError, ValueError, RuntimeError, TypeError) as error:
            raise CheckpointError(f'{replay_path}: does not fit this learner ({error})') from error


def export_policy(learner, path) -> None:
    """A small file with the actor alone: an expert node can serve it (a learner becomes a teacher)."""
    _atomic_save({
        'format': POLICY_FORMAT, 'version': FORMAT_VERSION,
        'obs_dim': learner.obs_dim, 'hidden': list(learner.config.hidden),
        'action_low': learner.scaler.low.tolist(), 'action_high': learner.scaler.high.tolist(),
        'actor': learner.actor.state_dict(),
    }, path)


class PolicyExpert:
    """An expert that answers with an exported policy's deterministic action tanh(mean)."""

    def __init__(self, path, name: str = 'policy'):
        data = _safe_load(path, POLICY_FORMAT)
        try:
            self.scaler = ActionScaler(data['action_low'], data['action_high'])
            self.obs_dim = int(data['obs_dim'])
            self.actor = SquashedGaussianActor(self.obs_dim, self.scaler.dim, tuple(data['hidden']))
            self.actor.load_state_dict(data['actor'])
        except (KeyError, ValueError, RuntimeError, TypeError) as error:
            raise CheckpointError(f'{path}: broken policy file ({error})') from error
        self.actor.eval()
        self.name = name

    @torch.no_grad()
    def action(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32).reshape(-1)
        if obs.shape[0] != self.obs_dim:
            raise ValueError(f'observation has {obs.shape[0]} values, the policy expects {self.obs_dim}')
        mean, _ = self.actor(torch.from_numpy(obs).unsqueeze(0))
        return self.scaler.to_env(torch.tanh(mean)[0].numpy())

    def __call__(self, request: AdviceRequest) -> Advice:
        return Advice(self.action(request.observation), expert_name=self.name)
