"""The motion models a belief filter assumes for its target (``env.belief.model``), batched.

A model is what a filter needs of a target: its state layout (``dim``, which entry is an angle, where
its velocity is), its transition ``f(x)`` and the process noise covariance ``Q`` added after it. The
model a filter assumes need not be the one the true targets follow (:mod:`aia.envs.targets`): that is
how a setting states a model mismatch.

* ``double_integrator``: ``[x, y, vx, vy]``, linear, ``Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]``
  (SPEC 3); the only model the Kalman filter (``kf``) takes.
* ``se2``: ``[x, y, theta]`` moved by the unicycle at a control ``(v, w)`` the filter does not know:
  ``belief.control`` says what it assumes (``zero``: the target stays, its uncertainty grows by
  ``Q = q dt I``; ``random``: a control drawn each step, ``v ~ U[0, 1)``, ``w ~ U[-pi/2, pi/2)``, as
  ttenv's UKF draws it); ttenv v2's belief.
* ``se2_velocity``: ``[x, y, theta, v, w]`` at constant speeds, ``Q = diag(q dt^3/3 I_3, q [[dt, dt^2/2],
  [dt^2/2, dt]])``; ttenv v3's belief (with the belief's own ``(v, w)``, where ttenv passes a random one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from aia.envs.belief import bmm
from aia.envs.config import BELIEF_MODELS
from aia.envs.dynamics import double_integrator, se2_step


@dataclass(frozen=True)
class BeliefModel:
    """A filter's target model: state layout, transition and process noise (tensors on the env's device)."""

    name: str
    dim: int
    angle: int | None           # index of the heading entry (circular mean, wrapped residuals), or None
    noise: Tensor                # [dim, dim] process noise covariance Q
    transition: Tensor | None    # [dim, dim] A when the model is linear, else None
    dt: float
    control: str = "zero"        # se2 only: the control the filter assumes (CONTROLS)

    @property
    def has_velocity(self) -> bool:
        """Whether the state carries a velocity (the features then hold the radial and angular rates)."""
        return self.name != "se2"

    @property
    def speed_entries(self) -> tuple[int, int] | None:
        """``(first, end)``: the slice of the state that holds speeds (what ``belief.speed_clip`` clips)."""
        return {"double_integrator": (2, 4), "se2_velocity": (3, 4)}.get(self.name)

    @property
    def random_controls(self) -> int:
        """Uniforms a step of :meth:`propagate` takes per target (the ``random`` control's two)."""
        return 2 if self.name == "se2" and self.control == "random" else 0

    def propagate(self, state: Tensor, uniforms: Tensor | None = None) -> Tensor:
        """``f(state)`` for ``state [..., dim]`` (sigma points or particles included); ``uniforms [..., 2]``
        (broadcast over the trailing points) draw the ``random`` control of ``se2``."""
        if self.transition is not None:
            return bmm(state.unsqueeze(-2), self.transition.mT).squeeze(-2)
        if self.name == "se2_velocity":
            return torch.cat((se2_step(state[..., :3], state[..., 3:], self.dt), state[..., 3:]), -1)
        if uniforms is None:
            return state  # zero control: the unicycle stays where it is
        control = torch.stack((uniforms[..., 0], (uniforms[..., 1] - 0.5) * math.pi), -1)
        return se2_step(state, control.expand(*state.shape[:-1], 2), self.dt)

    def velocity(self, mean: Tensor) -> Tensor:
        """``[..., 2]`` the velocity ``(vx, vy)`` in the world frame of belief means ``[..., dim]``."""
        if self.name == "double_integrator":
            return mean[..., 2:4]
        theta, speed = mean[..., 2], mean[..., 3]
        return torch.stack((speed * torch.cos(theta), speed * torch.sin(theta)), -1)

    def initial_mean(self, xy: Tensor, heading: Tensor) -> Tensor:
        """``[..., dim]`` the mean at the start of an episode: position ``xy [..., 2]``, heading ``[...]`` where
        the state has one, zero velocity."""
        zeros = torch.zeros_like(xy)
        if self.name == "double_integrator":
            return torch.cat((xy, zeros), -1)
        if self.name == "se2":
            return torch.cat((xy, heading[..., None]), -1)
        return torch.cat((xy, heading[..., None], zeros), -1)


def belief_model(name: str, dt: float, q: float, control: str = "zero", device: torch.device | str = "cpu",
                 dtype: torch.dtype = torch.float32) -> BeliefModel:
    """The model ``name`` (one of :data:`BELIEF_MODELS`) with process noise constant ``q``."""
    if name == "double_integrator":
        transition, noise = double_integrator(dt, q)
        return BeliefModel(name, 4, None, noise.to(device, dtype), transition.to(device, dtype), dt)
    if name == "se2":
        noise = q * dt * torch.eye(3, dtype=torch.float64)
        return BeliefModel(name, 3, 2, noise.to(device, dtype), None, dt, control)
    if name == "se2_velocity":
        noise = torch.zeros(5, 5, dtype=torch.float64)
        noise[:3, :3] = q * dt**3 / 3 * torch.eye(3, dtype=torch.float64)
        noise[3:, 3:] = q * torch.tensor([[dt, dt**2 / 2], [dt**2 / 2, dt]], dtype=torch.float64)
        return BeliefModel(name, 5, 2, noise.to(device, dtype), None, dt)
    raise ValueError(f"belief model {name!r} is not one of {list(BELIEF_MODELS)}")
