"""A trained policy as an expert: exported to a small file, served by an expert node (a learner becomes a teacher)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..algorithm.networks import SquashedGaussianActor
from ..data.advice import Advice, AdviceRequest
from ..data.errors import CheckpointError
from ..data.torch_files import FORMAT_VERSION, atomic_save, safe_load
from ..envs.spec import ActionScaler

POLICY_FORMAT = 'eqhrl_ros.policy'


def export_policy(learner, path) -> None:
    """A small file with the actor alone: an expert node can serve it (a learner becomes a teacher).
    A learner with a camera adds its camera's sizes and its encoder (the actor reads the encoder's
    features); such a file is not served as an expert yet."""
    policy = {
        'format': POLICY_FORMAT,
        'version': FORMAT_VERSION,
        'obs_dim': learner.obs_dim,
        'hidden': list(learner.config.hidden),
        'action_low': learner.scaler.low.tolist(),
        'action_high': learner.scaler.high.tolist(),
        'actor': {k: v.cpu() for k, v in learner.actor.state_dict().items()},
    }
    observation = learner.observation
    if observation.camera is not None and observation.encoder is not None:
        policy['camera'] = dataclasses.asdict(observation.camera)
        policy['state_dim'] = observation.state_dim
        policy['encoder'] = {k: v.cpu() for k, v in observation.encoder.state_dict().items()}
    atomic_save(policy, path)


class PolicyExpert:
    """An expert that answers with an exported policy's deterministic action tanh(mean)."""

    def __init__(self, path, name: str = 'policy'):
        data = safe_load(path, POLICY_FORMAT)
        if 'camera' in data:
            raise CheckpointError(
                f'{path}: this policy reads a camera; an advice request carries the vector alone, '
                'so it cannot be served as an expert yet'
            )
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
