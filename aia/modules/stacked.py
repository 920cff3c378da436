"""``StackedQNetwork``: the Q-networks of ``P`` independent learners as one module with a leading member dim.

A population trains ``P`` copies of one architecture. Their parameters live stacked, ``weight [P, in, out]``
and ``bias [P, 1, out]`` per layer, and the forward pass is one ``torch.baddbmm`` per layer: member ``k``'s
slice of the input ``[P, ..., in]`` meets only member ``k``'s weights, so gradients of a sum of the members'
losses reach each member's slice exactly as its own loss's gradients would. Because the member dimension is
inside the network, TorchRL's ``DQNLoss`` and :class:`~aia.losses.ADFQLoss` run unchanged on batches shaped
``[P, B]`` (they are shape-agnostic); no ``vmap`` over the loss is needed.

Why not ``torch.vmap`` over the loss with ``TensorDict.from_modules`` parameters: measured on a 2-core CPU
(3 x 128, batch 64, forward and backward), vmapped ``DQNLoss`` took 6-22 ms per update at P = 1
and 14-44 ms at P = 20, and ``torch.compile`` around it did not help (graph breaks), against about 1.6 ms at
P = 1 and 0.68 ms per member at P = 20 for a batched-linear network (``benchmarks/population.py`` measures
both).

Member ``k`` is built from an ordinary network (:func:`~aia.modules.make_q_network` or
:class:`~aia.modules.ADFQNetwork`, e.g. initialised under member ``k``'s seed): :meth:`StackedQNetwork.stack`
copies the networks in, :meth:`StackedQNetwork.unstack_into` writes member ``k`` back into such a network (its
checkpoint is then the one a solo run of that network writes).

:class:`StackedConvQNetwork` stacks :class:`~aia.modules.ConvQNetwork` s the same way: grouped convolutions for
the torsos, a :class:`StackedQNetwork` for the heads.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from aia.modules.q_networks import ADFQNetwork, ConvQNetwork


def _linears(network: nn.Module) -> tuple[list[nn.Linear], type[nn.Module]]:
    """The linear layers of an MLP (TorchRL's ``MLP`` or an :class:`ADFQNetwork`) and its activation class."""
    mlp = network.mlp if isinstance(network, ADFQNetwork) else network
    layers = list(mlp)
    linears = [layer for layer in layers if isinstance(layer, nn.Linear)]
    activations = {type(layer) for layer in layers if not isinstance(layer, nn.Linear)}
    if not linears or len(activations) > 1 or len(layers) != 2 * len(linears) - 1:
        raise TypeError(f"expected an MLP of alternating Linear layers and one activation, got {mlp}")
    return linears, activations.pop() if activations else nn.Identity


class StackedQNetwork(nn.Module):
    """``P`` MLP Q-networks (or ADFQ mean/log-sd networks) evaluated as one: ``[P, ..., in] -> [P, ..., A]``.

    Parameters are named ``weight{i}`` (``[P, in, out]``) and ``bias{i}`` (``[P, 1, out]``) for layer ``i``.
    For ADFQ networks (``log_sd_bounds`` given) the output is ``(mean, log_sd)`` with the log sd clamped, as
    :class:`~aia.modules.ADFQNetwork` returns it.
    """

    def __init__(self, weights: Sequence[Tensor], biases: Sequence[Tensor], activation: type[nn.Module],
                 log_sd_bounds: tuple[float, float] | None = None, inner_dtype: torch.dtype | None = None) -> None:
        super().__init__()
        if len(weights) != len(biases) or not weights:
            raise ValueError(f"need one bias per weight, got {len(weights)} weights and {len(biases)} biases")
        for i, (weight, bias) in enumerate(zip(weights, biases, strict=True)):
            self.register_parameter(f"weight{i}", nn.Parameter(weight))
            self.register_parameter(f"bias{i}", nn.Parameter(bias))
        self.num_layers = len(weights)
        self.activation = activation()
        self.log_sd_bounds = log_sd_bounds
        self.inner_dtype = inner_dtype

    @classmethod
    def stack(cls, networks: Sequence[nn.Module], inner_dtype: torch.dtype | None = None) -> StackedQNetwork:
        """One stacked network holding a copy of each of ``networks`` (same architecture), member ``k`` =
        ``networks[k]``; ``inner_dtype``: see :meth:`forward`."""
        layers = [_linears(network) for network in networks]
        activation = layers[0][1]
        shapes = [[tuple(linear.weight.shape) for linear in linears] for linears, _ in layers]
        if any(shape != shapes[0] for shape in shapes) or any(act is not activation for _, act in layers):
            raise ValueError(f"the members' networks differ in architecture: {sorted(set(map(str, shapes)))}")
        kinds = {(type(n).__name__, getattr(n, "log_sd_min", None), getattr(n, "log_sd_max", None)) for n in networks}
        if len(kinds) > 1:
            raise ValueError(f"the members' networks differ in kind or sd bounds: {sorted(map(str, kinds))}")
        weights = [torch.stack([linears[i].weight.detach().t() for linears, _ in layers]).contiguous()
                   for i in range(len(shapes[0]))]
        biases = [torch.stack([linears[i].bias.detach() for linears, _ in layers]).unsqueeze(1).contiguous()
                  for i in range(len(shapes[0]))]
        first = networks[0]
        bounds = (first.log_sd_min, first.log_sd_max) if isinstance(first, ADFQNetwork) else None
        return cls(weights, biases, activation, bounds, inner_dtype)

    @property
    def num_members(self) -> int:
        """``P``, the size of the leading member dimension."""
        return self.weight0.shape[0]

    def unstack_into(self, member: int, network: nn.Module) -> nn.Module:
        """Copy member ``member``'s parameters into ``network`` (of the stacked architecture); returns it."""
        linears, _ = _linears(network)
        with torch.no_grad():
            for i, linear in enumerate(linears):
                linear.weight.copy_(getattr(self, f"weight{i}")[member].t())
                linear.bias.copy_(getattr(self, f"bias{i}")[member, 0])
        return network

    def load_member(self, member: int, network: nn.Module) -> None:
        """Overwrite member ``member``'s parameters with ``network``'s (the inverse of :meth:`unstack_into`)."""
        linears, _ = _linears(network)
        with torch.no_grad():
            for i, linear in enumerate(linears):
                getattr(self, f"weight{i}")[member].copy_(linear.weight.t())
                getattr(self, f"bias{i}")[member, 0].copy_(linear.bias)

    def layer_dtype(self, layer: int) -> torch.dtype:
        """The dtype layer ``layer``'s matmul runs in (see :meth:`forward`)."""
        inner = self.inner_dtype is not None and 0 < layer < self.num_layers - 1
        return self.inner_dtype if inner else self.weight0.dtype

    def in_layer_dtypes(self, params: dict[str, Tensor]) -> dict[str, Tensor]:
        """``params`` (named as this network's) cast to the dtype their layer multiplies in, so that
        :meth:`forward` casts nothing: for parameters that serve many forward passes unchanged, e.g. the
        evaluation snapshots of :class:`~aia.modules.SnapshotPolicy`, whose 150-step rollouts of 250 worlds cast
        their bfloat16 layers' weights once instead of every step."""
        return {f"{kind}{i}": params[f"{kind}{i}"].to(self.layer_dtype(i))
                for i in range(self.num_layers) for kind in ("weight", "bias")}

    def forward(self, obs: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """Q-values ``[P, ..., A]`` (ADFQ: ``(mean, log_sd)``) of ``obs`` ``[P, ..., in]``, member by member.

        With ``inner_dtype`` set (``torch.bfloat16``), the layers between two hidden layers (all but the first
        and the last: 92 % of the paper networks' matmul arithmetic) multiply their inputs and weights cast to
        that dtype (the matmul accumulates in float32 and rounds its output to ``inner_dtype``); the first layer
        sees the observation and the last layer writes the Q-values in the parameters' dtype, and the
        parameters, gradients and optimiser stay in it.
        """
        members, *batch, features = obs.shape
        x = obs.reshape(members, -1, features)
        last = self.num_layers - 1
        for i in range(self.num_layers):
            weight, bias, dtype = getattr(self, f"weight{i}"), getattr(self, f"bias{i}"), self.layer_dtype(i)
            x = torch.baddbmm(bias.to(dtype), x.to(dtype), weight.to(dtype))  # .to: no copy where dtypes agree
            if i < last:
                x = self.activation(x)
        out = x.reshape(members, *batch, x.shape[-1])
        if self.log_sd_bounds is None:
            return out
        mean, log_sd = out.chunk(2, dim=-1)
        return mean, log_sd.clamp(*self.log_sd_bounds)


def _channels_last(x: Tensor) -> Tensor:
    """``x`` ``[N, C, H, W]`` laid out channels-last (the strides ``contiguous(memory_format=torch.channels_last)``
    gives), copied only where it is not; written with permutes so that it also runs under ``torch.vmap`` (the
    evaluation snapshots, :class:`~aia.modules.SnapshotPolicy`), which cannot query a memory format."""
    return x.permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2)


class StackedConvQNetwork(nn.Module):
    """``P`` :class:`~aia.modules.ConvQNetwork` s evaluated as one: ``observation`` ``[P, ..., F]`` and
    ``local_map`` ``[P, ..., C, H, W]`` to the heads' outputs ``[P, ..., A]`` (ADFQ: ``(mean, log_sd)``).

    The torsos' convolution ``i`` is one grouped convolution (``groups=P``, parameters ``conv_weight{i}``
    ``[P, out, in, k, k]`` and ``conv_bias{i}`` ``[P, out]``) over the members' images laid side by side in the
    channels (channels-last): member ``k``'s channels meet only member ``k``'s filters. The heads are one
    :class:`StackedQNetwork` (``head``), its ``inner_dtype`` as there. Measured on the 2-core CPU with
    ``benchmarks/population.py --conv-alternatives`` (the ttenv v4 DQN network, one thread, other jobs running,
    three runs): forward and backward of 64 transitions per member at P = 20 took 66-85 ms grouped against
    96-123 ms for ``torch.vmap`` over ``torch.func.stack_module_state`` and 103-190 ms for a loop over the
    members; acting on 4,096 worlds, 79-92 ms against 116-165 (vmap) and 72-102 (loop); at P = 1 the three are
    alike (7-10 and 48-92 ms). Channels-last: the torsos alone at P = 20, 34-39 ms against 55-64 ms in the
    default layout.
    """

    in_keys = ConvQNetwork.in_keys

    def __init__(self, conv_weights: Sequence[Tensor], conv_biases: Sequence[Tensor],
                 paddings: Sequence[tuple[int, ...]], strides: Sequence[int], activation: type[nn.Module],
                 head: StackedQNetwork) -> None:
        super().__init__()
        if not len(conv_weights) == len(conv_biases) == len(paddings) == len(strides) > 0:
            raise ValueError(f"need a bias, a padding and a stride per convolution, got {len(conv_weights)} "
                             f"weights, {len(conv_biases)} biases, {len(paddings)} paddings, {len(strides)} strides")
        for i, (weight, bias) in enumerate(zip(conv_weights, conv_biases, strict=True)):
            self.register_parameter(f"conv_weight{i}", nn.Parameter(weight))
            self.register_parameter(f"conv_bias{i}", nn.Parameter(bias))
        self.paddings = [tuple(padding) for padding in paddings]
        self.strides = list(strides)
        self.activation = activation()
        self.head = head

    @classmethod
    def stack(cls, networks: Sequence[ConvQNetwork], inner_dtype: torch.dtype | None = None) -> StackedConvQNetwork:
        """One stacked network holding a copy of each of ``networks`` (same architecture), member ``k`` =
        ``networks[k]``; ``inner_dtype``: the heads' (:meth:`StackedQNetwork.forward`)."""
        torsos = [network.torso.convolutions() for network in networks]
        shapes = {str([(tuple(conv.weight.shape), conv.stride, padding) for conv, padding in layers]
                      + [network.torso.activation_class.__name__])
                  for layers, network in zip(torsos, networks, strict=True)}
        if len(shapes) > 1:
            raise ValueError(f"the members' conv torsos differ in architecture: {sorted(shapes)}")
        layers = torsos[0]
        weights = [torch.stack([t[i][0].weight.detach() for t in torsos]) for i in range(len(layers))]
        biases = [torch.stack([t[i][0].bias.detach() for t in torsos]) for i in range(len(layers))]
        head = StackedQNetwork.stack([network.head for network in networks], inner_dtype)
        return cls(weights, biases, [padding for _, padding in layers], [conv.stride[0] for conv, _ in layers],
                   networks[0].torso.activation_class, head)

    @property
    def num_members(self) -> int:
        """``P``, the size of the leading member dimension."""
        return self.head.num_members

    @property
    def log_sd_bounds(self) -> tuple[float, float] | None:
        """The heads' log-sd bounds (ADFQ), else ``None``."""
        return self.head.log_sd_bounds

    def _pairs(self, network: ConvQNetwork) -> list[tuple[nn.Parameter, nn.Parameter, nn.Conv2d]]:
        return [(getattr(self, f"conv_weight{i}"), getattr(self, f"conv_bias{i}"), conv)
                for i, (conv, _) in enumerate(network.torso.convolutions())]

    def unstack_into(self, member: int, network: ConvQNetwork) -> ConvQNetwork:
        """Copy member ``member``'s parameters into ``network`` (of the stacked architecture); returns it."""
        with torch.no_grad():
            for weight, bias, conv in self._pairs(network):
                conv.weight.copy_(weight[member])
                conv.bias.copy_(bias[member])
        self.head.unstack_into(member, network.head)
        return network

    def load_member(self, member: int, network: ConvQNetwork) -> None:
        """Overwrite member ``member``'s parameters with ``network``'s (the inverse of :meth:`unstack_into`)."""
        with torch.no_grad():
            for weight, bias, conv in self._pairs(network):
                weight[member].copy_(conv.weight)
                bias[member].copy_(conv.bias)
        self.head.load_member(member, network.head)

    def in_layer_dtypes(self, params: dict[str, Tensor]) -> dict[str, Tensor]:
        """``params`` (named as this network's) with the heads' cast as :meth:`StackedQNetwork.in_layer_dtypes`
        casts them; the convolutions run in the parameters' dtype."""
        head = self.head.in_layer_dtypes({name[len("head."):]: value for name, value in params.items()
                                          if name.startswith("head.")})
        return {**{name: value for name, value in params.items() if name.startswith("conv_")},
                **{f"head.{name}": value for name, value in head.items()}}

    def forward(self, observation: Tensor, local_map: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """The heads' outputs on ``cat(torso features, observation)``, member by member."""
        members, *batch, channels, height, width = local_map.shape
        images = local_map.reshape(members, -1, channels, height, width)
        count = images.shape[1]
        x = images.transpose(0, 1).reshape(count, members * channels, height, width)
        x = _channels_last(x)
        for i, (padding, stride) in enumerate(zip(self.paddings, self.strides, strict=True)):
            weight = _channels_last(getattr(self, f"conv_weight{i}").flatten(0, 1))
            bias = getattr(self, f"conv_bias{i}").flatten()
            # the convolution pads both sides alike (F.pad would copy the images); TensorFlow's odd cell after
            before = padding[0]
            if padding[1] != before:
                x = F.pad(x, (0, padding[1] - before, 0, padding[3] - before))
            x = self.activation(F.conv2d(x, weight, bias, stride, before, groups=members))
        features = x.reshape(count, members, -1).transpose(0, 1).reshape(members, *batch, -1)
        return self.head(torch.cat([features, observation], dim=-1))
