"""The optimiser step of a population: loss, gradients, per-member clipping, Adam with per-member learning rates.

The members' parameters are stacked on a leading dimension ``P`` (:class:`~aia.modules.StackedQNetwork`), so
each parameter tensor holds one slice per member. Everything here is element-wise or reduced per member:

* the loss module runs with ``reduction="none"``; the objective is the sum over members of each member's
  mean loss, whose gradient in member ``k``'s slice is exactly the gradient of member ``k``'s own mean loss;
* gradient-norm clipping (``torch.nn.utils.clip_grad_norm_``'s rule, ``max_norm / (norm + 1e-6)`` capped at
  1) uses each member's own norm over all its parameters, never a norm mixed over members;
* Adam's arithmetic is ``torch.optim.Adam``'s default single-tensor step (bit for bit for one member; a test
  checks it), with the step size ``lr / (1 - beta1^t)`` a ``[P]`` tensor broadcast over each slice.

Why a hand-written Adam: ``torch.optim.Adam`` takes one learning rate per parameter group and a stacked
tensor cannot be split across groups, so per-member learning rates need the step written out. Written out,
it also compiles into one graph with the loss and its backward (``compile=True``): a whole update of the
paper's 3 x 256 ADFQ network took 1.3-1.8 ms on the 2-core CPU, against 2.2 ms with ``torch.optim.adam``'s
own arithmetic traced into the graph, which recomputed its bias corrections per element
(``benchmarks/train_throughput.py``).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torch._dynamo.exc import BackendCompilerFailed
from torch._inductor.exc import InductorError
from torchrl.objectives import HardUpdate, LossModule

from aia.runtime.compiling import compiled_update


class StackedAdam:
    """Adam's moments and step count for stacked parameters, with one learning rate per member.

    ``params`` are the trainable tensors, each ``[P, ...]``; ``lrs`` holds the ``P`` learning rates. The step
    count is shared (members update in lockstep).
    """

    def __init__(self, params: Sequence[Tensor], lrs: Sequence[float], betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.params = list(params)
        members = self.params[0].shape[0]
        if len(lrs) != members or any(p.shape[0] != members for p in self.params):
            raise ValueError(f"need one learning rate per member and [P, ...] parameters; got {len(lrs)} rates "
                             f"for parameters shaped {[tuple(p.shape) for p in self.params]}")
        if any(not lr > 0 for lr in lrs):
            raise ValueError(f"learning rates must be > 0, got {list(lrs)}")
        device, dtype = self.params[0].device, self.params[0].dtype
        self.lrs = torch.tensor(list(lrs), dtype=torch.float64, device=device)  # on the device: no copy a step
        self.betas = betas
        self.eps = eps
        self.step_count = 0
        self.exp_avgs = [torch.zeros_like(p) for p in self.params]
        self.exp_avg_sqs = [torch.zeros_like(p) for p in self.params]
        # This step's lr / (1 - beta1^t) per member, and sqrt(1 - beta2^t): filled before each step.
        self.step_sizes = torch.zeros(members, dtype=dtype, device=device)
        self.bias_correction2_sqrt = torch.zeros((), dtype=dtype, device=device)

    def advance(self) -> None:
        """Count one more step and set its bias corrections (no device sync: no host-to-device copy)."""
        self.step_count += 1
        beta1, beta2 = self.betas
        self.step_sizes.copy_(self.lrs / (1 - beta1**self.step_count))  # float64 quotients, rounded in the copy
        self.bias_correction2_sqrt.fill_((1 - beta2**self.step_count) ** 0.5)


class Updater:
    """One optimiser step per call: per-member losses, gradients, clipping, Adam, target bookkeeping.

    ``compile=True`` runs :func:`update_step` through ``torch.compile`` (forward, backward, clipping and Adam
    fused, in one graph for one member and two for more; the first call compiles;
    :func:`aia.runtime.compiling.compiled_update`: the loss module's settings must not change after that call); eager
    and compiled agree up to float rounding. The hard target-network copy (``target_updater.step()``) stays
    outside the graphs; ``on_target_copy`` is called after each copy. If inductor fails to compile the step, the
    updater says so in one line and runs it eager from then on: a compiler bug must not end a run that eager
    mode trains correctly (torch 2.13's CPU backend crashed on the one-graph step of two or more members,
    pytorch/pytorch#196570, until it was split in two graphs).
    """

    def __init__(self, loss: LossModule, optimizer: StackedAdam, target_updater: HardUpdate,
                 grad_clip: float, compile: bool = False, on_target_copy: Callable[[], None] | None = None) -> None:
        self.loss = loss
        self.on_target_copy = on_target_copy
        self.optimizer = optimizer
        self.target_updater = target_updater
        self.grad_clip = float(grad_clip)
        self._step = update_step
        if compile and optimizer.params[0].shape[0] == 1:
            self._step = compiled_update(update_step)
        elif compile:
            # Two or more members' step is two graphs (to the clipping factors; Adam): torch 2.13's CPU inductor
            # fuses their per-member norms into Adam's in-place updates and crashes (KeyError 'bufN',
            # pytorch/pytorch#196570). One member keeps one graph: 0.94-1.01 against 1.65-1.86 ms per 3x128
            # update in 2,000-frame jobs. Two compiled functions rather than a graph break in one:
            # dynamo traced the step twice to place the break, 2.3 s of each population's first update (5
            # members of 3 x 256), and the clipping factor now multiplies inside Adam's kernel.
            self._step = functools.partial(update_step, gradients=compiled_update(clipped_gradients),
                                           adam=compiled_update(clipped_adam_update))

    def __call__(self, batch: TensorDictBase) -> Tensor:
        """Update on ``batch`` (``[P, B]``); returns the ``[P]`` members' mean losses, detached."""
        opt = self.optimizer
        opt.advance()
        args = (self.loss, batch, opt.params, opt.exp_avgs, opt.exp_avg_sqs, opt.step_sizes,
                opt.bias_correction2_sqrt, self.grad_clip, *opt.betas, opt.eps)
        try:
            losses = self._step(*args)
        except (InductorError, BackendCompilerFailed) as err:  # raised while compiling, before the step ran
            if self._step is update_step:
                raise
            reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            print(f"compile.update: torch.compile could not compile the update step ({reason[:200]}); "
                  "it runs eager", file=sys.stderr)
            self._step = update_step
            losses = self._step(*args)
        # HardUpdate copies at the step whose counter has reached the interval (then restarts the count)
        copies = self.target_updater.counter == self.target_updater.value_network_update_interval
        self.target_updater.step()
        if copies and self.on_target_copy is not None:
            self.on_target_copy()
        return losses


def clipped_gradients(loss: LossModule, batch: TensorDictBase, params: list[Tensor], grad_clip: float
                      ) -> tuple[Tensor, tuple[Tensor, ...], Tensor]:
    """The members' mean losses ``[P]`` (detached), the gradients of their sum, and each member's clipping
    factor ``[P]``: ``clip_grad_norm_``'s ``max_norm / (norm + 1e-6)`` capped at 1, over its own parameters."""
    member_losses = loss(batch)["loss"].flatten(1).mean(-1)  # reduction="none": [P, B] -> [P]
    members = member_losses.shape[0]
    grads = torch.autograd.grad(member_losses.sum(), params)
    # clip_grad_norm_'s norm, per member (written out: _foreach_norm has no inductor kernel)
    norms = torch.stack([torch.linalg.vector_norm(g.reshape(members, -1), dim=-1) for g in grads], dim=-1)
    scale = torch.clamp(grad_clip / (torch.linalg.vector_norm(norms, dim=-1) + 1e-6), max=1.0)
    return member_losses.detach(), grads, scale


def clipped_adam_update(params: list[Tensor], grads: Sequence[Tensor], scale: Tensor, exp_avgs: list[Tensor],
                        exp_avg_sqs: list[Tensor], step_sizes: Tensor, bias_correction2_sqrt: Tensor, beta1: float,
                        beta2: float, eps: float) -> None:
    """:func:`adam_update` with member ``k``'s gradients multiplied by ``scale[k]`` (clipping)."""
    with torch.no_grad():
        members = scale.shape[0]
        scaled = [g * scale.reshape(members, *(1,) * (g.ndim - 1)) for g in grads]
        adam_update(params, scaled, exp_avgs, exp_avg_sqs, step_sizes, bias_correction2_sqrt, beta1, beta2, eps)


def update_step(loss: LossModule, batch: TensorDictBase, params: list[Tensor], exp_avgs: list[Tensor],
                exp_avg_sqs: list[Tensor], step_sizes: Tensor, bias_correction2_sqrt: Tensor, grad_clip: float,
                beta1: float, beta2: float, eps: float, gradients: Callable = clipped_gradients,
                adam: Callable = clipped_adam_update) -> Tensor:
    """The members' mean losses ``[P]``, their gradients, per-member clipping and :func:`adam_update` in place:
    ``gradients`` (:func:`clipped_gradients`, or a compiled copy), then ``adam`` (:func:`clipped_adam_update`)."""
    losses, grads, scale = gradients(loss, batch, params, grad_clip)
    adam(params, grads, scale, exp_avgs, exp_avg_sqs, step_sizes, bias_correction2_sqrt, beta1, beta2, eps)
    return losses


def adam_update(params: list[Tensor], grads: list[Tensor], exp_avgs: list[Tensor], exp_avg_sqs: list[Tensor],
                step_sizes: Tensor, bias_correction2_sqrt: Tensor, beta1: float, beta2: float, eps: float) -> None:
    """Adam's update of stacked ``params`` and their moments in place, as ``torch.optim.Adam``'s single-tensor
    step (no weight decay, amsgrad or maximize) with member ``k``'s step size ``step_sizes[k]``.

    The operations and their order are those of ``torch.optim.adam._single_tensor_adam``, so for one member
    the eager result is the same to the bit.
    """
    for param, grad, exp_avg, exp_avg_sq in zip(params, grads, exp_avgs, exp_avg_sqs, strict=True):
        exp_avg.lerp_(grad, 1 - beta1)
        exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(eps)
        param.sub_(step_sizes.reshape(-1, *(1,) * (param.ndim - 1)) * exp_avg / denom)
