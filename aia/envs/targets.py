"""How the true targets move (``env.target.model``), batched over ``[B, N]`` worlds and targets.

A model owns the layout of ``target_state [B, N, D]`` (the position always first, ``[..., :2]``), the number
of standard normals it takes per target and step, its initial state and its step. Every model keeps its
targets in free space: a move into collision keeps the position.

* ``double_integrator`` ``[x, y, vx, vy]`` (SPEC 3): ``x' = A x + w``, ``w ~ N(0, W)``; the speed optionally
  rescaled to ``speed_limit``. ``collision_rule="reflect"`` (2019): a colliding move keeps the position and
  reflects the velocity, ``v <- gain v' + N(0, std^2)``. ``"detour"`` (ttenv v1's obstacle-aware targets):
  with ``(d, beta)`` the distance and bearing (from the velocity's direction) of the nearest obstacle, a
  colliding move keeps the position and leaves at speed ``|v| + N(0, 1)`` in the direction ``beta -+ (1 + U)
  pi/2`` (away from the obstacle's side); and every step the velocity gains ``dt * a (cos, sin)(beta -+ rot)``
  with ``a = max(0, |v| cos beta) / max(floor, d - detour_margin)``, ``rot = pi/2 (1 + sigmoid(|v| -
  detour_speed))``: a push away from what the target is heading into.
* ``evasive`` ``[x, y, vx, vy]`` (new): the double integrator driven, while the robot is within ``flee_range``
  of it, by an acceleration of ``flee_accel`` straight away from the robot, held over the step: ``x' = A x +
  [dt^2/2 I; dt I] a + w``; then the collision rule and the speed limit as above. Out of that range it is
  the plain double integrator.
* ``se2_sine`` ``[x, y, theta, v, w, ox, oy, otheta]`` (ttenv v2's ``SinePolicy``): the target follows the
  curve ``y = b sin(a x)`` of a frame at ``(ox, oy, otheta)``, steering each step to the curve's point
  ``x_step`` further on: ``w = wrap(theta* - theta) / dt``, ``v = |p* - p| / dt``, clipped to the speed limits,
  then the unicycle moves exactly. A colliding move keeps the position, and the curve starts again from there
  with a heading turned by ``U(-turn, turn)``.
* ``se2_constant`` ``[x, y, theta, v, w]`` (ttenv v3's ``ConstantPolicy``): each step the speeds take a
  Gaussian step, ``(v, w) <- clip((v, w) + N(0, q [[dt, dt^2/2], [dt^2/2, dt]]))``, and the unicycle moves. A
  colliding move is replaced by the mirrored turn ``(v, -w)`` from the same start (ttenv's rule); if that
  collides too, the target keeps its position and turns around (ttenv lets it into the obstacle).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import torch
from torch import Tensor

from aia.envs import belief
from aia.envs.dynamics import double_integrator, se2_step, wrap_angle
from aia.envs.sensing import Geometry


class TargetModel(ABC):
    """The true targets' motion: ``dim`` state entries, ``normals`` draws per target and step, and which
    entry is the heading (``heading``: None when the state has none)."""

    dim: int
    normals: int
    heading: int | None = None

    def __init__(self, geometry: Geometry, dt: float) -> None:
        self.geometry = geometry
        self.dt = dt

    @abstractmethod
    def initial(self, xy: Tensor, heading: Tensor) -> Tensor:
        """``[B, N, dim]`` the state at an episode's start at ``xy [B, N, 2]`` facing ``heading [B, N]``."""

    @abstractmethod
    def step(self, state: Tensor, normals: Tensor, robot_pose: Tensor) -> Tensor:
        """The next ``state [B, N, dim]``, from ``normals [B, N, self.normals]`` standard normals; the
        robot's ``pose [B, 3]`` after its move is there for the models that react to it."""


class DoubleIntegratorTargets(TargetModel):
    """SPEC 3's targets with the 2019 reflection rule (see the module docstring)."""

    dim, normals = 4, 6

    def __init__(self, geometry: Geometry, dt: float, q: float, reflect_gain: float, reflect_noise_std: float,
                 speed_limit: float | None, collision_rule: str = "reflect", detour_margin: float = 3.5,
                 detour_speed: float = 1.75, detour_floor: float = 1.0) -> None:
        super().__init__(geometry, dt)
        self.collision_rule = collision_rule
        self.detour_margin, self.detour_speed, self.detour_floor = detour_margin, detour_speed, detour_floor
        if collision_rule == "detour" and geometry.has_obstacles:
            geometry.nearest_obstacle_table()
        transition, noise = double_integrator(dt, q)
        # W is positive definite for q > 0 (its 2x2 block has determinant q^2 dt^4 / 12).
        chol = torch.linalg.cholesky(noise) if q > 0 else torch.zeros(4, 4, dtype=torch.float64)
        self.transition = transition.to(geometry.device, geometry.dtype)
        self.noise_chol = chol.to(geometry.device, geometry.dtype)
        self.reflect_gain, self.reflect_noise_std, self.speed_limit = reflect_gain, reflect_noise_std, speed_limit

    def initial(self, xy: Tensor, heading: Tensor) -> Tensor:
        return torch.cat((xy, torch.zeros_like(xy)), -1)

    def step(self, state: Tensor, normals: Tensor, robot_pose: Tensor) -> Tensor:
        moved = belief.bmm(state.unsqueeze(-2), self.transition.mT).squeeze(-2)
        moved = moved + belief.bmm(normals[..., :4].unsqueeze(-2), self.noise_chol.mT).squeeze(-2)
        moved = self._accelerate(moved, state, robot_pose)
        bounced = self.geometry.in_collision(moved[..., :2])
        if self.collision_rule == "reflect":
            bounce_velocity = self.reflect_gain * moved[..., 2:] + self.reflect_noise_std * normals[..., 4:6]
        else:
            bounce_velocity, push = self._detour(state, normals[..., 4:6])
        moved = torch.where(bounced[..., None], torch.cat((state[..., :2], bounce_velocity), -1), moved)
        if self.collision_rule == "detour":
            moved = torch.cat((moved[..., :2], moved[..., 2:] + push), -1)
        if self.speed_limit is not None:
            speed = torch.linalg.vector_norm(moved[..., 2:], dim=-1, keepdim=True)
            scale = torch.clamp(self.speed_limit / speed.clamp_min(1e-12), max=1.0)
            moved = torch.cat((moved[..., :2], moved[..., 2:] * scale), -1)
        return moved


    def _accelerate(self, moved: Tensor, state: Tensor, robot_pose: Tensor) -> Tensor:
        """The move with the step's own acceleration added (none: the plain double integrator)."""
        return moved

    def _detour(self, state: Tensor, normals: Tensor) -> tuple[Tensor, Tensor]:
        """ttenv v1's ``(velocity after a collision, the step's push)`` from the current ``state``."""
        velocity = state[..., 2:]
        heading = torch.atan2(velocity[..., 1], velocity[..., 0])
        speed = torch.linalg.vector_norm(velocity, dim=-1)
        distance, direction = self.geometry.nearest_obstacle(state[..., :2])
        bearing = wrap_angle(direction - heading)
        side = torch.where(bearing >= 0, -1.0, 1.0)
        uniform = _uniform(normals[..., 1])
        leave = bearing + side * (1.0 + uniform) * (math.pi / 2) + heading
        leave_speed = speed + normals[..., 0]
        after_collision = leave_speed.unsqueeze(-1) * torch.stack((torch.cos(leave), torch.sin(leave)), -1)
        turn = (math.pi / 2) * (1.0 + torch.sigmoid(speed - self.detour_speed))
        ahead = (speed * torch.cos(bearing)).clamp_min(0.0)
        accel = ahead / (distance - self.detour_margin).clamp_min(self.detour_floor)
        push_angle = bearing + side * turn + heading
        push = (self.dt * accel).unsqueeze(-1) * torch.stack((torch.cos(push_angle), torch.sin(push_angle)), -1)
        return after_collision, push


class EvasiveTargets(DoubleIntegratorTargets):
    """Double-integrator targets that flee the robot within ``flee_range`` (see the module docstring)."""

    def __init__(self, *args, flee_range: float, flee_accel: float, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.flee_range, self.flee_accel = flee_range, flee_accel

    def _accelerate(self, moved: Tensor, state: Tensor, robot_pose: Tensor) -> Tensor:
        away = state[..., :2] - robot_pose[:, None, :2]
        distance = torch.linalg.vector_norm(away, dim=-1, keepdim=True)
        accel = torch.where(distance <= self.flee_range, self.flee_accel * away / distance.clamp_min(1e-9), 0.0)
        return moved + torch.cat((0.5 * self.dt**2 * accel, self.dt * accel), -1)


class SineTargets(TargetModel):
    """ttenv v2's sine-following SE(2) targets (see the module docstring)."""

    dim, normals, heading = 8, 1, 2

    def __init__(self, geometry: Geometry, dt: float, step_length: float, frequency: float, amplitude: float,
                 speed_limit: float, angular_speed_limit: float, turn: float) -> None:
        super().__init__(geometry, dt)
        self.step_length, self.frequency, self.amplitude, self.turn = step_length, frequency, amplitude, turn
        self.limits = (speed_limit, angular_speed_limit)

    def initial(self, xy: Tensor, heading: Tensor) -> Tensor:
        pose = torch.cat((xy, heading.unsqueeze(-1)), -1)
        return torch.cat((pose, torch.zeros_like(xy), pose), -1)

    def step(self, state: Tensor, normals: Tensor, robot_pose: Tensor) -> Tensor:
        pose, origin, frame = state[..., :3], state[..., 5:7], state[..., 7]
        cos, sin = torch.cos(frame), torch.sin(frame)
        rel = pose[..., :2] - origin
        along = cos * rel[..., 0] + sin * rel[..., 1] + self.step_length     # the curve's next abscissa
        across = self.amplitude * torch.sin(self.frequency * along)
        goal = origin + torch.stack((cos * along - sin * across, sin * along + cos * across), -1)
        slope = self.amplitude * self.frequency * torch.cos(self.frequency * along)
        goal_heading = wrap_angle(torch.atan(slope) + frame)
        v_max, w_max = self.limits
        v = (torch.linalg.vector_norm(goal - pose[..., :2], dim=-1) / self.dt).clamp(-v_max, v_max)
        w = (wrap_angle(goal_heading - pose[..., 2]) / self.dt).clamp(-w_max, w_max)
        control = torch.stack((v, w), -1)
        moved = se2_step(pose, control, self.dt)
        blocked = self.geometry.in_collision(moved[..., :2])
        kept = torch.cat((pose[..., :2], moved[..., 2:]), -1)
        moved = torch.where(blocked[..., None], kept, moved)
        # A blocked target starts its curve again where it stands, turned by U(-turn, turn).
        uniform = _uniform(normals[..., 0])
        new_frame = wrap_angle(moved[..., 2] + (2.0 * uniform - 1.0) * self.turn)
        restart = torch.cat((moved[..., :2], new_frame.unsqueeze(-1)), -1)
        curve = torch.where(blocked[..., None], restart, state[..., 5:])
        return torch.cat((moved, control, curve), -1)


class ConstantSpeedTargets(TargetModel):
    """ttenv v3's SE(2) targets with noisy constant speeds (see the module docstring)."""

    dim, normals, heading = 5, 2, 2

    def __init__(self, geometry: Geometry, dt: float, q: float, speed_limit: float,
                 angular_speed_limit: float) -> None:
        super().__init__(geometry, dt)
        noise = q * torch.tensor([[dt, dt**2 / 2], [dt**2 / 2, dt]], dtype=torch.float64)
        chol = torch.linalg.cholesky(noise) if q > 0 else torch.zeros(2, 2, dtype=torch.float64)
        self.noise_chol = chol.to(geometry.device, geometry.dtype)
        self.limit = torch.tensor([speed_limit, angular_speed_limit], dtype=geometry.dtype, device=geometry.device)
        self.mirror = torch.tensor([1.0, -1.0], dtype=geometry.dtype, device=geometry.device)  # (v, w) -> (v, -w)

    def initial(self, xy: Tensor, heading: Tensor) -> Tensor:
        return torch.cat((xy, heading.unsqueeze(-1), torch.zeros_like(xy)), -1)

    def step(self, state: Tensor, normals: Tensor, robot_pose: Tensor) -> Tensor:
        pose = state[..., :3]
        control = state[..., 3:] + belief.bmm(normals.unsqueeze(-2), self.noise_chol.mT).squeeze(-2)
        control = torch.maximum(torch.minimum(control, self.limit), -self.limit)
        moved = se2_step(pose, control, self.dt)
        mirrored_control = control * self.mirror
        mirrored = se2_step(pose, mirrored_control, self.dt)
        turned = torch.cat((pose[..., :2], wrap_angle(pose[..., 2:] + math.pi)), -1)
        blocked = self.geometry.in_collision(moved[..., :2])
        mirror_blocked = self.geometry.in_collision(mirrored[..., :2])
        fallback = torch.where(mirror_blocked[..., None], turned, mirrored)
        moved = torch.where(blocked[..., None], fallback, moved)
        control = torch.where(blocked[..., None], mirrored_control, control)
        return torch.cat((moved, control), -1)


def _uniform(normal: Tensor) -> Tensor:
    """Uniforms in (0, 1) from standard normals (their CDF): a model's uniform draw from the step's normals."""
    return 0.5 * (1.0 + torch.erf(normal / math.sqrt(2.0)))
