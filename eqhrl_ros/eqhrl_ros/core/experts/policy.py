"""A trained policy as an expert: exported to a small file, served by an expert node (a learner becomes a teacher)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..algorithm.networks import SquashedGaussianActor
from ..algorithm.observations import CameraObservation, VectorObservation
from ..data.advice import Advice, AdviceRequest
from ..data.errors import CheckpointError
from ..data.torch_files import FORMAT_VERSION, atomic_save, safe_load
from ..envs.spec import ActionScaler, CameraSpec

POLICY_FORMAT = 'eqhrl_ros.policy'


def export_policy(learner, path) -> None:
    """A small file with the actor alone: an expert node can serve it (a learner becomes a teacher).
    A learner with a camera adds its camera's sizes and its encoder (the actor reads the encoder's
    features); served as an expert, it reads the frames each request carries."""
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
    """An expert that answers with an exported policy's deterministic action tanh(mean); a camera
    policy's from the request's state vector and the frames it carries."""

    def __init__(self, path, name: str = 'policy'):
        data = safe_load(path, POLICY_FORMAT)
        try:
            self.scaler = ActionScaler(data['action_low'], data['action_high'])
            self.observation = self._observation(data)
            self.obs_dim = self.observation.state_dim  # the vector a request carries
            features = self.observation.features_dim
            self.actor = SquashedGaussianActor(features, self.scaler.dim, tuple(data['hidden']))
            self.actor.load_state_dict(data['actor'])
        except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as error:
            raise CheckpointError(f'{path}: broken policy file ({error})') from error
        networks = [self.actor, *([self.observation.encoder] if self.observation.encoder is not None else [])]
        if not all(torch.isfinite(p).all() for network in networks for p in network.parameters()):
            raise CheckpointError(f'{path}: the policy holds non-finite weights (NaN or inf)')
        for network in networks:
            network.eval()
        self.name = name
        self.camera = self.observation.camera
        self.observation_size, self.action_size = self.obs_dim, self.scaler.dim

    @staticmethod
    def _observation(data: dict):
        """What the policy reads: a vector, or a state vector and a camera's stack, through its encoder."""
        cpu = torch.device('cpu')
        if 'camera' not in data:
            return VectorObservation(int(data['obs_dim']), cpu)
        observation = CameraObservation(int(data['state_dim']), CameraSpec(**data['camera']), cpu)
        observation.make_encoder().load_state_dict(data['encoder'])
        return observation

    @torch.no_grad()
    def action(self, obs, pixels=None) -> np.ndarray:
        """The action for ``obs`` (a camera policy: the state vector, with ``pixels`` its stack)."""
        if self.camera is None:
            obs = np.asarray(obs, dtype=np.float32).reshape(-1)
            if obs.shape[0] != self.obs_dim:
                raise ValueError(f'observation has {obs.shape[0]} values, the policy expects {self.obs_dim}')
        else:
            obs = {'state': obs, 'pixels': pixels}
        observation = self.observation
        mean, _ = self.actor(observation.features(observation.tensor(obs)))
        return self.scaler.to_env(torch.tanh(mean)[0].numpy())

    def __call__(self, request: AdviceRequest) -> Advice:
        if self.camera is not None and request.pixels is None:
            return Advice.decline('this policy reads a camera, and the request carries no frames', self.name)
        return Advice(self.action(request.observation, request.pixels), expert_name=self.name)
