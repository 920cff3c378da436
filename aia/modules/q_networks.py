"""Q-networks for the tracking env: a plain MLP (DQN, Double DQN), a mean/log-sd MLP (ADFQ), and either of them
behind a convolutional torso over a map image (:class:`ConvQNetwork`).

The MLPs map the transformed env's ``observation`` ``[..., 6N+2]`` to one output per motion primitive.
:func:`make_qvalue_actor` wraps any of them into a TorchRL policy: a ``TensorDictModule`` that writes
``action_value`` (and, for ADFQ, ``action_log_sd``) followed by TorchRL's ``QValueModule``, which writes
the greedy ``action`` (an integer index for the ``Categorical`` action spec) and ``chosen_action_value``
(``[..., 1]``, the value of that action).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import Tensor, nn
from torchrl.data import Categorical, Composite, TensorSpec
from torchrl.modules import MLP, QValueModule

from aia.config.checks import ConvLayers, check_number

OBSERVATION_KEY, MAP_KEY = "observation", "local_map"
# the authors' conv layers (filters, kernel, stride) for ttenv's map observations (ADFQ's cnn_plus_mlp, ReLU,
# TensorFlow's "SAME" padding, no pooling): 28 x 28 -> 4 x 7 x 7 -> 8 x 4 x 4, 128 features
CONV_LAYERS: tuple[tuple[int, int, int], ...] = ((4, 8, 4), (8, 4, 2))

ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU}


def _activation(name: str) -> type[nn.Module]:
    try:
        return ACTIVATIONS[name]
    except KeyError:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {name!r}") from None


def make_q_network(
    obs_dim: int, num_actions: int, hidden: Sequence[int] = (128, 128, 128), activation: str = "relu"
) -> nn.Module:
    """An MLP ``obs_dim -> hidden... -> num_actions`` (the paper: 3 x 128 for 1 target, 3 x 256 for 2-3)."""
    return MLP(
        in_features=obs_dim,
        out_features=num_actions,
        num_cells=list(hidden),
        activation_class=_activation(activation),
    )


class ADFQNetwork(nn.Module):
    """ADFQ Q-network: an MLP whose ``2 A`` outputs are a mean and a log standard deviation per action.

    The log sd is clamped to ``[log sqrt(var_min), log sd_max]`` (reference defaults ``varth = 1e-10``, so
    ``sd >= 1e-5``, and ``sd_max = 1e5``). The output layer starts with zero weights and biases ``init_mean``
    for the means and ``log(init_sd)`` for the log sds, so at initialisation every action has exactly mean
    ``init_mean`` (1) and sd ``init_sd`` (10) whatever the input, as in the reference: greedy ties are exact
    and only Thompson sampling or epsilon-greedy break them. The zero weights still receive gradients (the
    hidden activations are non-zero), so the trunk starts learning from the second update on.
    """

    def __init__(
        self,
        obs_dim: int,
        num_actions: int,
        hidden: Sequence[int] = (128, 128, 128),
        activation: str = "relu",
        var_min: float = 1e-10,
        sd_max: float = 1e5,
        init_mean: float = 1.0,
        init_sd: float = 10.0,
    ) -> None:
        super().__init__()
        self.num_actions = num_actions
        self.log_sd_min = 0.5 * math.log(var_min)
        self.log_sd_max = math.log(sd_max)
        self.mlp = MLP(
            in_features=obs_dim,
            out_features=2 * num_actions,
            num_cells=list(hidden),
            activation_class=_activation(activation),
        )
        head = self.mlp[-1]
        with torch.no_grad():
            head.weight.zero_()
            head.bias[:num_actions] = init_mean
            head.bias[num_actions:] = math.log(init_sd)

    def forward(self, obs: Tensor) -> tuple[Tensor, Tensor]:
        """``(mean, log_sd)``, each ``[..., A]``, with ``log_sd`` clamped to the sd bounds."""
        mean, log_sd = self.mlp(obs).split(self.num_actions, dim=-1)
        return mean, log_sd.clamp(self.log_sd_min, self.log_sd_max)


def same_padding(size: int, kernel: int, stride: int) -> tuple[int, int, int]:
    """TensorFlow's ``"SAME"`` padding of one spatial dim: ``(before, after, output size)``, the output
    ``ceil(size / stride)`` and the odd cell of the padding after (the authors' networks are TensorFlow's)."""
    out = -(-size // stride)
    total = max((out - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2, out


class ConvTorso(nn.Sequential):
    """Convolutions over a ``[..., channels, im_size, im_size]`` map image, each padded as TensorFlow's
    ``"SAME"`` and followed by the activation; :attr:`out_features` per image (flattened channel-major).

    ``layers``: ``(filters, kernel, stride)`` per convolution (default: the authors', :data:`CONV_LAYERS`).
    A channel count or image size below 1 is refused with a one-line :class:`~aia.config.errors.ConfigError`.
    """

    def __init__(self, channels: int, im_size: int, layers: Sequence[Sequence[int]] = CONV_LAYERS,
                 activation: str = "relu") -> None:
        check_number("local_map.channels", channels, ge=1, integer=True)
        check_number("local_map.im_size", im_size, ge=1, integer=True)
        layers = [list(layer) for layer in layers]
        ConvLayers()("conv_layers", layers)
        modules: list[nn.Module] = []
        size = im_size
        activation_class = _activation(activation)
        for filters, kernel, stride in layers:
            before, after, size = same_padding(size, kernel, stride)
            modules += [nn.ZeroPad2d((before, after, before, after)), nn.Conv2d(channels, filters, kernel, stride),
                        activation_class()]
            channels = filters
        super().__init__(*modules)
        self.activation_class = activation_class
        self.out_features = channels * size * size

    def convolutions(self) -> list[tuple[nn.Conv2d, tuple[int, int, int, int]]]:
        """The convolutions, first to last, each with its padding ``(left, right, top, bottom)``."""
        modules = list(self)
        return [(conv, pad.padding) for pad, conv in zip(modules[0::3], modules[1::3], strict=True)]


class ConvQNetwork(nn.Module):
    """A Q-network over a map image and the belief features: ``head(cat(torso(local_map), observation))``.

    ``torso``: a :class:`ConvTorso`; ``head``: an MLP (:func:`make_q_network`) or an :class:`ADFQNetwork` whose
    input is the torso's features followed by the ``F`` belief features (the authors' order), so the output is
    the head's: Q-values ``[..., A]``, or ADFQ's ``(mean, log_sd)``. Inputs: ``observation`` ``[..., F]`` and
    ``local_map`` ``[..., C, H, W]`` with the same leading dims (:attr:`in_keys`: the tensordict keys, read by
    :func:`make_qvalue_actor`). All ``C`` channels enter the torso (the authors' network took only the first
    ``H * W`` values of ttenv v5's flattened 5-channel image as its one channel).
    """

    in_keys = (OBSERVATION_KEY, MAP_KEY)

    def __init__(self, torso: ConvTorso, head: nn.Module) -> None:
        super().__init__()
        self.torso = torso
        self.head = head

    def forward(self, observation: Tensor, local_map: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """The head's output on the torso's features of ``local_map`` and ``observation``."""
        *batch, channels, height, width = local_map.shape
        features = self.torso(local_map.reshape(-1, channels, height, width)).reshape(*batch, -1)
        return self.head(torch.cat([features, observation], dim=-1))


def _unbatched_categorical(action_spec: TensorSpec) -> Categorical:
    """The per-world ``Categorical`` spec of a (possibly batched, possibly composite) action spec."""
    if isinstance(action_spec, Composite):
        action_spec = action_spec["action"]
    if not isinstance(action_spec, Categorical):
        raise TypeError(f"expected a Categorical action spec, got {type(action_spec).__name__}")
    return Categorical(action_spec.space.n, device=action_spec.device, dtype=action_spec.dtype)


class _DirectOutputModule(TensorDictModule):
    """A ``TensorDictModule`` that writes its tensor outputs into the input tensordict as they are.

    tensordict 0.14 passes every output through ``TensorDict.from_any``, which returns a tensor unchanged but
    first asks ``importlib.util.find_spec("pandas")``: a search of ``sys.path`` on every call when pandas is
    not installed, about 0.1 ms per output, i.e. per policy step at batch size 1. Other cases (outputs that
    are not tensors, a separate output tensordict) go through the parent's code.
    """

    def _write_to_tensordict(self, tensordict, tensors, tensordict_out=None, out_keys=None):
        if tensordict_out is not None or self.inplace is not True or not all(isinstance(t, Tensor) for t in tensors):
            return super()._write_to_tensordict(tensordict, tensors, tensordict_out, out_keys)
        out_keys = self.out_keys_source if out_keys is None else out_keys
        if len(tensors) != len(out_keys):
            raise RuntimeError(f"{len(tensors)} outputs for the out_keys {list(out_keys)}")
        for key, tensor in zip(out_keys, tensors, strict=True):
            if key != "_":
                tensordict.set(key, tensor)
        return tensordict


def network_in_keys(network: nn.Module, in_key: str = OBSERVATION_KEY) -> list[str]:
    """The tensordict keys ``network`` reads, in its arguments' order: the ``in_keys`` a network names (the conv
    networks': observation, local_map), else ``[in_key]``."""
    return list(getattr(network, "in_keys", [in_key]))


def make_qvalue_actor(
    network: nn.Module, action_spec: TensorSpec, in_key: str = OBSERVATION_KEY, adfq: bool = False
) -> TensorDictSequential:
    """A greedy Q-value policy: ``network`` on ``in_key`` (or on the keys a network with ``in_keys`` names, e.g.
    :class:`ConvQNetwork`'s) then TorchRL's ``QValueModule``.

    Writes ``action_value`` (the Q-values, or the ADFQ means), for ADFQ also ``action_log_sd``, then
    ``action`` (argmax index, int64, shape = batch shape) and ``chosen_action_value`` (``[..., 1]``).
    ``action_spec`` may be the env's batched ``env.action_spec`` (``Categorical`` of shape ``[B]``), its
    unbatched form or ``env.full_action_spec``: it is reduced to a shape-``()`` ``Categorical``, which
    ``QValueModule`` needs to accept any leading batch shape (a batched spec makes it expect ``[B, B]``).
    """
    out_keys = ["action_value", "action_log_sd"] if adfq else ["action_value"]
    value_module = _DirectOutputModule(network, in_keys=network_in_keys(network, in_key), out_keys=out_keys)
    return TensorDictSequential(value_module, QValueModule(spec=_unbatched_categorical(action_spec)))
