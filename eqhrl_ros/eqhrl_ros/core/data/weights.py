"""The networks an actor node needs, as bytes on the wire: safetensors, never pickle.

The trainer sends its actor (the policy) and its twin critics (an actor node evaluates D(s)
with them, Eq. 8) every few updates, and a camera learner's image encoder (both read its
features). safetensors holds only named tensors and a JSON header: reading it cannot run code,
unlike torch.save's pickle. Names are ``actor.<key>``, ``critic.<key>`` and ``encoder.<key>`` of
the state dicts.
"""

from __future__ import annotations

import torch
from safetensors import SafetensorError
from safetensors.torch import load, save

NETWORKS = ('actor', 'critic')


def _networks(learner) -> dict:
    """The modules sent, by name: the actor and critics, and a camera learner's encoder."""
    networks = {name: getattr(learner, name) for name in NETWORKS}
    encoder = learner.observation.encoder
    return networks if encoder is None else {**networks, 'encoder': encoder}


# How the trainer may send the tensors (weights_on_wire): float16 halves the bytes; the trainer
# keeps learning in float32 and an actor casts them back to its own float32 on arrival.
WIRE_DTYPES = {'float32': torch.float32, 'float16': torch.float16}


class WeightsError(ValueError):
    """Weights that this learner cannot take: not safetensors, other names or shapes, NaN."""


def encode_weights(learner, wire_dtype: str = 'float32') -> bytes:
    """The learner's actor and twin critics as safetensors bytes, floating tensors in ``wire_dtype``."""
    dtype = WIRE_DTYPES[wire_dtype]
    tensors = {}
    for network, module in _networks(learner).items():
        for key, tensor in module.state_dict().items():
            tensor = tensor.detach().cpu()
            tensors[f'{network}.{key}'] = (tensor.to(dtype) if tensor.is_floating_point() else tensor).contiguous()
    return save(tensors)


def apply_weights(learner, data: bytes) -> None:
    """Load weights from encode_weights() into ``learner``'s actor and critics, whole or not at
    all: names, shapes and finiteness are checked before any tensor is copied."""
    try:
        tensors = load(bytes(data))
    except (SafetensorError, ValueError, OSError) as error:
        raise WeightsError(f'not safetensors data: {error}') from error
    states, networks = {}, _networks(learner)
    unknown = [name for name in tensors if name.split('.', 1)[0] not in networks]
    if unknown:  # first: another kind of learner's (a camera's encoder) says so, not a shape
        raise WeightsError(f'unexpected tensors {sorted(unknown)[:5]}')
    absent = [network for network in networks if not any(name.startswith(f'{network}.') for name in tensors)]
    if absent:  # a camera learner given a vector learner's weights: no encoder
        raise WeightsError(f'no {" or ".join(absent)} tensors in these weights')
    for network, module in networks.items():
        own = module.state_dict()
        prefix = f'{network}.'
        received = {name[len(prefix) :]: t for name, t in tensors.items() if name.startswith(prefix)}
        if set(received) != set(own):
            missing, extra = sorted(set(own) - set(received)), sorted(set(received) - set(own))
            raise WeightsError(f"{network} tensors differ from this learner's: missing {missing}, unexpected {extra}")
        for key, tensor in received.items():
            narrower = tensor.dtype in WIRE_DTYPES.values() and own[key].dtype == torch.float32
            if tensor.shape != own[key].shape or (tensor.dtype != own[key].dtype and not narrower):
                raise WeightsError(
                    f'{network}.{key} is {tuple(tensor.shape)} {tensor.dtype}, this learner has '
                    f'{tuple(own[key].shape)} {own[key].dtype} (other hidden_sizes?)'
                )
            if tensor.is_floating_point() and not torch.isfinite(tensor).all():
                raise WeightsError(f'{network}.{key} holds non-finite values (NaN or inf)')
            received[key] = tensor.to(own[key].dtype)  # float16 on the wire: back to float32
        states[network] = received
    for network, state in states.items():
        networks[network].load_state_dict(state)


# How far one weights message may move an actor on. A trainer publishes every weights_every
# updates; an actor that missed weights for hours of updates at 1 kHz still sees a smaller step.
MAX_VERSION_JUMP = 10_000_000
MAX_EPISODE_JUMP = 1_000_000
INT32_MAX = 2**31 - 1


class TrainerPin:
    """Which trainer's weights an actor obeys (nodes/actor_node.py asks before applying any).

    - It follows one trainer: the one ``trainer_id`` names, or (empty) the first whose weights it
      applies. Weights of another trainer are taken only when the actor is told to (trainer_id
      set to it) or when that trainer is the only one publishing weights (the one followed has
      left the graph: a trainer restarted, resumed or replaced), never beside the one followed.
    - Within a trainer, versions only increase (an older or repeated version is ignored) and may
      not jump by more than MAX_VERSION_JUMP; the episode count the budget (Eq. 7) follows may not
      pass the int32 range of the record or jump by more than MAX_EPISODE_JUMP.
    Without a shared key these rules cannot tell a forger that copies the followed trainer's id
    from that trainer; they keep a stranger with its own id out while the real trainer runs.
    """

    def __init__(self, trainer_id: str = ''):
        self.named = trainer_id  # set by the person (the trainer_id parameter); '' follows the first
        self.followed = trainer_id
        self.version: int | None = None

    def name(self, trainer_id: str) -> None:
        """Follow ``trainer_id`` from now on ('' : the next trainer that publishes alone)."""
        self.named = self.followed = trainer_id
        self.version = None

    def judge(self, trainer_id: str, version: int, episodes: int, episode_now: int, alone: bool) -> str:
        """'apply', 'stale' (an old version: ignore it) or why the weights are refused.
        ``alone``: the sender is the only publisher of weights on the graph."""
        if episodes > INT32_MAX or episodes - episode_now > MAX_EPISODE_JUMP:
            return f"their episode count {episodes} is {episodes - episode_now} past this actor's"
        if trainer_id != self.followed:
            if self.named and trainer_id != self.named:
                return f"they come from trainer '{trainer_id}', and this actor follows '{self.named}' (trainer_id)"
            if self.followed and not alone:
                return (
                    f"they come from trainer '{trainer_id}' while '{self.followed}' still publishes: this actor "
                    'follows the trainer it joined (set trainer_id to follow another)'
                )
            return 'apply'  # a new trainer, alone: it replaces the one followed
        if self.version is not None and version <= self.version:
            return 'stale'
        if self.version is not None and version - self.version > MAX_VERSION_JUMP:
            return f'version {version} jumps {version - self.version} past v{self.version}'
        return 'apply'

    def applied(self, trainer_id: str, version: int) -> None:
        self.followed, self.version = trainer_id, int(version)
