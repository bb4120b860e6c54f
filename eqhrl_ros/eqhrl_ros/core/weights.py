"""The networks an actor node needs, as bytes on the wire: safetensors, never pickle.

The trainer sends its actor (the policy) and its twin critics (an actor node evaluates D(s)
with them, Eq. 8) every few updates. safetensors holds only named tensors and a JSON header:
reading it cannot run code, unlike torch.save's pickle. Names are ``actor.<key>`` and
``critic.<key>`` of the two state dicts.
"""

from __future__ import annotations

import torch
from safetensors import SafetensorError
from safetensors.torch import load, save

NETWORKS = ('actor', 'critic')


class WeightsError(ValueError):
    """Weights that this learner cannot take: not safetensors, other names or shapes, NaN."""


def encode_weights(learner) -> bytes:
    """The learner's actor and twin critics as safetensors bytes."""
    tensors = {}
    for network in NETWORKS:
        for key, tensor in getattr(learner, network).state_dict().items():
            tensors[f'{network}.{key}'] = tensor.detach().cpu().contiguous()
    return save(tensors)


def apply_weights(learner, data: bytes) -> None:
    """Load weights from encode_weights() into ``learner``'s actor and critics, whole or not at
    all: names, shapes and finiteness are checked before any tensor is copied."""
    try:
        tensors = load(bytes(data))
    except (SafetensorError, ValueError, OSError) as error:
        raise WeightsError(f'not safetensors data: {error}') from error
    states = {}
    for network in NETWORKS:
        own = getattr(learner, network).state_dict()
        prefix = f'{network}.'
        received = {name[len(prefix) :]: t for name, t in tensors.items() if name.startswith(prefix)}
        if set(received) != set(own):
            missing, extra = sorted(set(own) - set(received)), sorted(set(received) - set(own))
            raise WeightsError(f"{network} tensors differ from this learner's: missing {missing}, unexpected {extra}")
        for key, tensor in received.items():
            if tensor.shape != own[key].shape or tensor.dtype != own[key].dtype:
                raise WeightsError(
                    f'{network}.{key} is {tuple(tensor.shape)} {tensor.dtype}, this learner has '
                    f'{tuple(own[key].shape)} {own[key].dtype} (other hidden_sizes?)'
                )
            if tensor.is_floating_point() and not torch.isfinite(tensor).all():
                raise WeightsError(f'{network}.{key} holds non-finite values (NaN or inf)')
        states[network] = received
    unknown = [name for name in tensors if name.split('.', 1)[0] not in NETWORKS]
    if unknown:
        raise WeightsError(f'unexpected tensors {sorted(unknown)[:5]}')
    for network, state in states.items():
        getattr(learner, network).load_state_dict(state)
