"""Motion models: the SE(2) robot driven by motion primitives and the double-integrator targets.

Pure batched functions of tensors; the env owns the state and the collision handling.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor


def wrap_angle(angle: Tensor) -> Tensor:
    """Wrap angles to [-pi, pi)."""
    return torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi


def motion_primitives(
    linear_speeds: Sequence[float], angular_speeds: Sequence[float], dtype: torch.dtype = torch.float32
) -> Tensor:
    """``[A, 2]`` table of (v, w) with the reference index order ``a = len(w) * i_v + i_w``."""
    v = torch.tensor(linear_speeds, dtype=dtype)
    w = torch.tensor(angular_speeds, dtype=dtype)
    return torch.stack(torch.broadcast_tensors(v[:, None], w[None, :]), dim=-1).reshape(-1, 2)


def se2_step(pose: Tensor, velocity: Tensor, dt: float) -> Tensor:
    """Exact unicycle integration over ``dt`` at constant (v, w).

    ``x' = x + v dt sinc(w dt / 2) cos(theta + w dt / 2)``, likewise ``y'`` with sin, and
    ``theta' = wrap(theta + w dt)``. ``pose`` is ``[..., 3]``, ``velocity`` is ``[..., 2]``.
    """
    half_turn, chord, turn = unicycle_arc(velocity, dt)
    heading = pose[..., 2] + half_turn
    return torch.stack(
        (
            pose[..., 0] + chord * torch.cos(heading),
            pose[..., 1] + chord * torch.sin(heading),
            wrap_angle(pose[..., 2] + turn),
        ),
        dim=-1,
    )


def unicycle_arc(velocity: Tensor, dt: float) -> tuple[Tensor, Tensor, Tensor]:
    """What :func:`se2_step` takes of ``velocity [..., 2]`` alone: the half turn ``w dt / 2``, the chord
    ``v dt sinc(w dt / 2)`` and the turn ``w dt`` (each ``[...]``)."""
    v, w = velocity.unbind(-1)
    half_turn = 0.5 * dt * w
    # torch.sinc is the normalised sinc sin(pi u) / (pi u); rescale to sin(u) / u.
    chord = v * dt * torch.sinc(half_turn / math.pi)
    return half_turn, chord, dt * w


def double_integrator(dt: float, q: float, dtype: torch.dtype = torch.float64) -> tuple[Tensor, Tensor]:
    """Transition matrix ``A`` and process-noise covariance ``W`` of the 2-D double integrator.

    State ``(p1, p2, v1, v2)``; ``A = [[I, dt I], [0, I]]``,
    ``W = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]``.
    """
    eye = torch.eye(2, dtype=dtype)
    zero = torch.zeros(2, 2, dtype=dtype)
    transition = torch.cat((torch.cat((eye, dt * eye), 1), torch.cat((zero, eye), 1)), 0)
    noise = q * torch.cat(
        (torch.cat((dt**3 / 3 * eye, dt**2 / 2 * eye), 1), torch.cat((dt**2 / 2 * eye, dt * eye), 1)), 0
    )
    return transition, noise
