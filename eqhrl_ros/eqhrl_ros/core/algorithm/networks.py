"""Actor and twin critics (Section 2.2, Table 1: 256x256, actor Tanh, critic ReLU, Kaiming init)."""

from __future__ import annotations

import os
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

# Range of the actor's log standard deviation, reached smoothly through a tanh
# (as in CleanRL) so that its gradient never vanishes at a hard clamp.
LOG_STD_MIN = -5.0
LOG_STD_MAX = 2.0


class _TanhGradient(torch.autograd.Function):
    """A tanh computed by a subclass's forward, with torch's tanh gradient 1 - tanh(x)^2 from its
    output. Written with setup_context so that torch.func's transforms (the update's gradients)
    can use it: they call forward with plain tensors."""

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        ctx.save_for_backward(output)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


class _NumpyTanh(_TanhGradient):
    """tanh on numpy's SIMD kernel.

    Why: this torch CPU build runs tanh element by element, several times slower than
    numpy's kernel on a batch, for the same values to 1 ulp (docs/performance.md).
    """

    @staticmethod
    def forward(x: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(np.tanh(x.detach().contiguous().numpy()))


class _ExpTanh(_TanhGradient):
    """tanh(x) = sign(x) (1 - e^{-2|x|}) / (1 + e^{-2|x|}), within 1e-7 of tanh.

    Why: compiled for the CPU, torch.tanh becomes Sleef's vector tanh, about twice the time of this
    form's one exponential (153 against 81 us on a 512x256 batch), and the actor's hidden tanh were
    the compiled update's largest kernels after the products (docs/performance.md).
    """

    @staticmethod
    def forward(x: torch.Tensor) -> torch.Tensor:
        t = torch.exp(-2.0 * x.abs())
        return torch.copysign((1.0 - t) / (1.0 + t), x)


NUMPY_TANH_FROM = 4096  # elements


def tanh(x: torch.Tensor) -> torch.Tensor:
    """torch.tanh, on numpy's kernel for a batch on CPU (see _NumpyTanh), and in the form of
    _ExpTanh in code that torch.compile traces for the CPU.

    Small inputs (acting on one observation) keep torch.tanh, where the autograd
    Function's own overhead would cost more than it saves; so do other devices and dtypes.
    """
    if x.numel() < NUMPY_TANH_FROM or x.device.type != 'cpu' or x.dtype != torch.float32:
        return torch.tanh(x)
    if torch.compiler.is_dynamo_compiling():  # (not is_compiling(): process-wide, update.tracing)
        return _ExpTanh.apply(x)
    return _NumpyTanh.apply(x)


class Module(nn.Module):
    """nn.Module, called through its own ``__call__``, fixed when this module is imported.

    Why: torch.fx's symbolic tracing replaces nn.Module.__call__ on the class, for every thread,
    while it traces, and inductor traces small functions so while compile_update compiles in its
    background thread. A network called meanwhile in another thread (acting, D(s), an eager
    update) went to the tracer and raised NameError('module is not installed as a submodule'):
    a trainer died so. The function is the same one (dynamo and torch.func see nn.Module's own)."""

    __call__ = nn.Module.__call__


class Tanh(Module):
    """nn.Tanh with the faster ``tanh`` above."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return tanh(x)


def linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """x @ weight.T + bias for one network (weight [out, in]), or for N stacked networks at once
    (weight [N, out, in], bias [N, out], x [N, batch, in]) with one batched product (stacked_seeds.py)."""
    if weight.dim() == 2:
        return F.linear(x, weight, bias)
    return biased_product(x, weight.transpose(-1, -2), bias.unsqueeze(-2))


def biased_product(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """bias + x @ weight for a stack of layers ([groups, batch, in] @ [groups, in, out]): one
    batched product with its bias (the twin critics, stacked networks). One function, so that
    benchmarks/kernel_options.py can measure the compiled update with the bias written apart."""
    return torch.baddbmm(bias, x, weight)


def _kaiming_linear(in_features: int, out_features: int, nonlinearity: Literal['relu', 'linear', 'tanh']) -> nn.Linear:
    layer = nn.Linear(in_features, out_features)
    nn.init.kaiming_uniform_(layer.weight, nonlinearity=nonlinearity)
    nn.init.zeros_(layer.bias)
    return layer


class SquashedGaussianActor(Module):
    """pi_phi(a|s): an MLP with Tanh hidden activations giving the mean and log-std of u; a = tanh(u)."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...] = (256, 256)):
        super().__init__()
        layers: list[nn.Module] = []
        width = obs_dim
        for size in hidden:
            layers += [_kaiming_linear(width, size, 'tanh'), Tanh()]
            width = size
        self.body = nn.Sequential(*layers)
        # Mean and log-std heads in one layer: one matmul instead of two.
        self.heads = _kaiming_linear(width, 2 * action_dim, 'linear')
        self.action_dim = action_dim
        # The body's Linear layers, called directly in forward: acting on one observation
        # is dominated by per-module call overhead, not arithmetic.
        self._hidden = [layer for layer in self.body if isinstance(layer, nn.Linear)]

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log_std) of u for each row of ``obs``; with stacked parameters (stacked_seeds.py),
        obs is [N, batch, obs_dim] and network k acts on obs[k]."""
        x = obs
        for layer in self._hidden:  # = self.body(obs)
            x = tanh(linear(x, layer.weight, layer.bias))
        mean, raw_log_std = linear(x, self.heads.weight, self.heads.bias).split(self.action_dim, dim=-1)
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (torch.tanh(raw_log_std) + 1.0)
        return mean, log_std

    def linear_layers(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(weight [out, in], bias [out]) of each layer in order, the heads last (mean rows
        first, then log-std): the parameters themselves, for readers that rebuild the maths."""
        return [(layer.weight, layer.bias) for layer in (*self._hidden, self.heads)]


def _tensors(parameters: nn.ParameterList) -> list[torch.Tensor]:
    """A ParameterList's tensors in order, read from its _parameters dict (always current, also
    after stacked_seeds.py replaces them). Iterating the list itself goes through __getitem__ and
    __getattr__ for each: 15 against 2 us for the twin critic's six, paid by acting on one
    observation (D(s)) and by every eager update."""
    return [tensor for tensor in parameters._parameters.values() if tensor is not None]


class TwinCritic(Module):
    """Q_theta1 and Q_theta2: two independent ReLU MLPs Q(s, a), evaluated as one batched network.

    Each layer stores both critics' weights stacked on a leading axis of size 2 and
    runs them with one batched matmul (torch.baddbmm): same maths as two separate
    MLPs, half the kernel launches. The last layer (width -> 1) is a dot product per
    row, computed as multiply-and-sum: faster than a batched matmul with one output
    column (docs/performance.md). ``forward`` returns
    (Q1, Q2), each of shape [batch].
    """

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...] = (256, 256)):
        super().__init__()
        sizes = [obs_dim + action_dim, *hidden, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for i, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            nonlinearity: Literal['relu', 'linear'] = 'relu' if i < len(sizes) - 2 else 'linear'
            weight = torch.empty(2, fan_in, fan_out)
            for critic in range(2):
                # kaiming_uniform_ on a [out, in] view so that fan_in is the layer's input size.
                nn.init.kaiming_uniform_(weight[critic].T, nonlinearity=nonlinearity)
            self.weights.append(nn.Parameter(weight))
            self.biases.append(nn.Parameter(torch.zeros(2, 1, fan_out)))

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(Q1, Q2) of each row. With stacked parameters (weights [N, 2, in, out]: N twin
        critics, stacked_seeds.py), obs and action are [N, batch, dim] and Q1, Q2 are [N, batch]."""
        *weights, last_weight = _tensors(self.weights)
        *biases, last_bias = _tensors(self.biases)
        lead = last_weight.shape[:-2]  # (2,), or (N, 2) when stacked
        x = torch.cat([obs, action], dim=-1)
        batch, width = x.shape[-2:]
        # Both critics (of every network) in one batched product per layer: [lead..., batch, width]
        # folded to [groups, batch, width]; a view, not a copy, for a single twin critic.
        x = x.unsqueeze(-3).expand(*lead, batch, width).reshape(-1, batch, width)
        for weight, bias in zip(weights, biases):
            x = torch.relu(
                biased_product(x, weight.reshape(-1, *weight.shape[-2:]), bias.reshape(-1, *bias.shape[-2:]))
            )
        # [groups, batch, width] * [groups, 1, width], summed over width: [groups, batch].
        q = (x * last_weight.reshape(-1, *last_weight.shape[-2:]).transpose(1, 2)).sum(-1) + last_bias.reshape(-1, 1)
        q = q.view(*lead, batch)
        return q[..., 0, :], q[..., 1, :]

    def linear_layers(self, k: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Critic k's (0 or 1) layers as an ordinary MLP: (weight [in, out], bias [out]) for
        h @ weight + bias, ReLU between layers, the last giving Q. Views of the parameters."""
        return [(weight[k], bias[k, 0]) for weight, bias in zip(self.weights, self.biases)]


# Floats a learner keeps per network weight: the actor's and the critics' weights, the target
# critics, the gradients and Adam's two moments (a trainer also keeps a finite copy of each).
FLOATS_PER_WEIGHT = 6


def weight_count(obs_dim: int, action_dim: int, hidden: tuple[int, ...]) -> int:
    """Weights and biases of the actor (its heads give mean and log-std) and the twin critic."""

    def layers(sizes: list[int]) -> int:
        return sum((fan_in + 1) * fan_out for fan_in, fan_out in zip(sizes[:-1], sizes[1:]))

    return layers([obs_dim, *hidden, 2 * action_dim]) + 2 * layers([obs_dim + action_dim, *hidden, 1])


def check_fits_in_memory(obs_dim: int, action_dim: int, hidden: tuple[int, ...], device: torch.device) -> None:
    """ValueError, naming the sizes, when networks of these sizes cannot fit in this machine's
    memory (CPU): refused at once, not a failed allocation's traceback (or the out-of-memory
    killer) once the node has started."""
    if device.type != 'cpu':
        return
    needed = 4 * FLOATS_PER_WEIGHT * weight_count(obs_dim, action_dim, hidden)
    try:
        memory = os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES')
    except (ValueError, OSError):  # not known here: the allocation itself will say
        return
    if needed > memory:
        raise ValueError(
            f'hidden sizes {list(hidden)} make networks of {weight_count(obs_dim, action_dim, hidden):,} weights, '
            f'about {needed / 2**30:,.0f} GiB with their targets, gradients and Adam moments; '
            f'this machine has {memory / 2**30:,.0f} GiB'
        )
