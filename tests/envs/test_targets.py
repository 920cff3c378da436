"""The true targets' models: free space, speed limits, headings, and ttenv's policies by hand."""

from __future__ import annotations

import math

import pytest
import torch

from aia.envs import make_env
from aia.envs.dynamics import se2_step
from aia.envs.sensing import map_geometry
from aia.envs.targets import ConstantSpeedTargets, DoubleIntegratorTargets, EvasiveTargets, SineTargets

ROBOT = torch.tensor([[1.0, 1.0, 0.0]], dtype=torch.float64)   # far from every target below


def _geometry(name="obstacles4"):
    return map_geometry(name, 0.5, 10.0, math.radians(120), 0.05, 4, "cpu", torch.float64)


@pytest.mark.parametrize("setting", ["ttenv_v2", "ttenv_v3"])
def test_se2_targets_stay_free_within_limits_and_wrapped(setting):
    env = make_env(setting, batch_size=32, seed=2, transforms=False, overrides=["map=obstacles4"])
    td = env.rollout(50, break_when_any_done=False)
    states = torch.cat((td["target_state"][:, :1], td["next", "target_state"]), 1)
    assert not env.geometry.in_collision(states[..., :2]).any()
    heading = states[..., 2]
    assert heading.abs().max() <= math.pi
    cfg = env.config.target
    assert states[..., 3].abs().max() <= cfg.speed_limit + 1e-6
    assert states[..., 4].abs().max() <= cfg.angular_speed_limit + 1e-6
    # a target moves by the unicycle at its recorded control, except where it was blocked
    before, after = states[:, :-1], states[:, 1:]
    moved = se2_step(before[..., :3], after[..., 3:5], env.config.dt)
    free = (moved - after[..., :3]).abs().amax(-1) < 1e-4
    assert free.float().mean() > 0.9


def test_sine_policy_follows_its_curve_by_hand():
    dt = 0.5
    model = SineTargets(_geometry("empty"), dt, step_length=0.1, frequency=0.5, amplitude=5.0, speed_limit=2.0,
                        angular_speed_limit=math.pi, turn=math.pi / 4)
    start = torch.tensor([[[50.0, 50.0, 0.0]]], dtype=torch.float64)
    state = model.initial(start[..., :2], start[..., 2])
    state = model.step(state, torch.zeros(1, 1, 1, dtype=torch.float64), ROBOT)
    # the frame is the start pose: the next curve point is (0.1, 5 sin(0.05)), its heading atan(2.5 cos(0.05))
    goal = torch.tensor([50.1, 50.0 + 5.0 * math.sin(0.05)], dtype=torch.float64)
    v = float(torch.linalg.vector_norm(goal - start[0, 0, :2])) / dt
    w = math.atan(2.5 * math.cos(0.05)) / dt
    w = max(-math.pi, min(math.pi, w))
    assert torch.allclose(state[0, 0, 3:5], torch.tensor([v, w], dtype=torch.float64))
    expected = se2_step(start[0, 0], torch.tensor([v, w], dtype=torch.float64), dt)
    assert torch.allclose(state[0, 0, :3], expected)
    assert torch.equal(state[0, 0, 5:], start[0, 0])  # the curve's frame is kept while the target is free


def test_constant_speed_target_mirrors_its_turn_at_an_obstacle():
    geometry = _geometry("empty_small")
    model = ConstantSpeedTargets(geometry, 0.5, q=0.0, speed_limit=2.0, angular_speed_limit=math.pi / 5)
    # 0.5 m from the east wall's margin, heading north-east, turning left: the move collides, the mirrored
    # turn (to the right) collides as well, so the target stays and turns around
    state = torch.tensor([[[26.0, 13.5, math.pi / 4, 2.0, 0.5]]], dtype=torch.float64)
    nxt = model.step(state, torch.zeros(1, 1, 2, dtype=torch.float64), ROBOT)
    assert torch.allclose(nxt[0, 0, :2], state[0, 0, :2])
    assert math.isclose(float(nxt[0, 0, 2]), math.pi / 4 - math.pi, abs_tol=1e-12)
    assert torch.allclose(nxt[0, 0, 3:], torch.tensor([2.0, -0.5], dtype=torch.float64))
    # heading along the wall, turning into it: the mirrored turn is free and taken
    state = torch.tensor([[[26.4, 13.5, math.pi / 2, 2.0, -0.6]]], dtype=torch.float64)
    nxt = model.step(state, torch.zeros(1, 1, 2, dtype=torch.float64), ROBOT)
    mirrored = se2_step(state[0, 0, :3], torch.tensor([2.0, 0.6], dtype=torch.float64), 0.5)
    assert torch.allclose(nxt[0, 0, :3], mirrored) and not geometry.in_collision(mirrored[:2])


def test_detour_targets_leave_an_obstacle_they_run_into_and_are_pushed_away_by_hand():
    geometry = _geometry("empty_small")
    model = DoubleIntegratorTargets(geometry, 0.5, q=0.0, reflect_gain=-0.4, reflect_noise_std=0.2, speed_limit=None,
                                    collision_rule="detour", detour_margin=3.5, detour_speed=1.75, detour_floor=0.5)
    # heading east at 2 m/s, 0.8 m from the east wall's margin (x = 26.5): the move collides
    state = torch.tensor([[[25.7, 13.5, 2.0, 0.0]]], dtype=torch.float64)
    normals = torch.tensor([[[0, 0, 0, 0, 0.3, 0.0]]], dtype=torch.float64)  # speed + 0.3, U = 1/2
    nxt = model.step(state, normals, ROBOT)
    assert torch.allclose(nxt[0, 0, :2], state[0, 0, :2])
    # the wall is straight ahead (bearing 0 >= 0): leave at 0 - 1.5 pi/2 from the heading, at 2.3 m/s
    leave = 2.3 * torch.tensor([math.cos(-0.75 * math.pi), math.sin(-0.75 * math.pi)], dtype=torch.float64)
    turn = math.pi / 2 * (1 + 1 / (1 + math.exp(-(2.0 - 1.75))))
    accel = 2.0 / max(0.5, 0.8 - 3.5)
    push = 0.5 * accel * torch.tensor([math.cos(-turn), math.sin(-turn)], dtype=torch.float64)
    assert torch.allclose(nxt[0, 0, 2:], leave + push)
    # moving away from the nearest wall (behind it): no push, the plain double integrator
    far = torch.tensor([[[25.0, 13.5, -1.0, 0.0]]], dtype=torch.float64)
    moved = torch.tensor([[[24.5, 13.5, -1.0, 0.0]]], dtype=torch.float64)
    assert torch.allclose(model.step(far, torch.zeros(1, 1, 6, dtype=torch.float64), ROBOT), moved)


def test_nearest_obstacle_by_hand():
    geometry = _geometry("obstacles4")
    xy = torch.tensor([[0.9, 18.0], [18.1, 1.3]], dtype=torch.float64)
    distance, direction = geometry.nearest_obstacle(xy)
    assert torch.allclose(distance, torch.tensor([0.4, 0.8], dtype=torch.float64))   # the walls, margin 0.5
    assert torch.allclose(direction, torch.tensor([math.pi, -math.pi / 2], dtype=torch.float64))
    occupied = geometry.map.occupancy.nonzero()[0]            # an occupied cell (row, col): its centre is at 0 m
    centre = (occupied.flip(0).double() + 0.5) * geometry.resolution
    distance, _ = geometry.nearest_obstacle(centre[None])
    assert float(distance[0]) < 1e-9


def test_evasive_targets_flee_the_robot_within_range_by_hand():
    geometry = _geometry("empty_small")
    model = EvasiveTargets(geometry, 0.5, 0.0, -0.4, 0.2, 2.0, flee_range=10.0, flee_accel=1.0)
    state = torch.tensor([[[13.5, 13.5, 0.0, 0.5], [13.5, 13.5, 0.0, 0.5]]], dtype=torch.float64)
    robot = torch.tensor([[10.5, 9.5, 0.0]], dtype=torch.float64)         # 5 m away, along (3, 4) / 5
    nxt = model.step(state, torch.zeros(1, 2, 6, dtype=torch.float64), robot)
    accel = torch.tensor([0.6, 0.8], dtype=torch.float64)
    expected = torch.cat((state[0, 0, :2] + 0.5 * state[0, 0, 2:] + 0.125 * accel, state[0, 0, 2:] + 0.5 * accel))
    assert torch.allclose(nxt[0, 0], expected)
    away = (nxt[0, 0, :2] - robot[0, :2]).norm() - (state[0, 0, :2] - robot[0, :2]).norm()
    assert away > 0
    # out of range it is the plain double integrator, and its speed stays within the limit
    far = model.step(state, torch.zeros(1, 2, 6, dtype=torch.float64), ROBOT)
    assert torch.allclose(far[0, 0], torch.tensor([13.5, 13.75, 0.0, 0.5], dtype=torch.float64))
    fast = torch.tensor([[[13.5, 13.5, 1.9, 0.0]]], dtype=torch.float64)
    assert float(model.step(fast, torch.zeros(1, 1, 6, dtype=torch.float64), robot)[0, 0, 2:].norm()) <= 2.0 + 1e-12
