"""``TargetTrackingEnv``: B independent tracking worlds stepped as one tensor program.

Each world holds a robot, ``N`` targets (a :class:`~aia.envs.targets.TargetModel`: SPEC 3's double
integrator by default) and one belief per target kept by a :class:`~aia.envs.filters.BeliefFilter` (SPEC
5's Kalman filter by default; SPEC 1-5). A step moves the robot by one of the motion primitives, moves the
targets, observes the visible ones with the range-bearing sensor, and hands the measurements to the filter,
which predicts every belief and updates the observed ones. The env emits the raw world state; the RL
observation and the shaped reward come from the transforms in :mod:`aia.transforms`.

Randomness comes from :mod:`aia.rng`: every world has its own reproducible stream keyed by the seed,
its index and its episode count, so partial resets of some worlds never change what the others draw.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from aia import rng
from aia.envs import belief
from aia.envs.belief_models import belief_model
from aia.envs.config import TrackingConfig, belief_model_name
from aia.envs.dynamics import motion_primitives, se2_step
from aia.envs.filters import FILTERS, BeliefFilter
from aia.envs.map_generator import RandomObstacles
from aia.envs.maps import RANDOM_MAP, GridMap, load_map
from aia.envs.sensing import Geometry, WorldMapGeometry, map_geometry
from aia.envs.targets import ConstantSpeedTargets, DoubleIntegratorTargets, EvasiveTargets, SineTargets, TargetModel
from aia.runtime.compiling import compiled


class TargetTrackingEnv(EnvBase):
    """Batched active target tracking (SPEC 1-5) as a native TorchRL env.

    Args:
        config: the setting (map, targets, sensor, belief...); see :class:`~aia.envs.config.TrackingConfig`.
        batch_size: number of independent worlds ``B`` (an int or ``(B,)``).
        device: where the state lives and the step runs.
        seed: seed of the per-world random streams (random when None).
        validate_actions: check every action index is in range (one device sync per step on CUDA).
        compile_step: run the physics of the step through ``torch.compile`` (fused kernels; the first step
            of each env compiles for ~10 s). Not to be confused with TorchRL's own ``compile=`` constructor
            argument, which compiles the whole ``step_and_maybe_reset``.

    Emitted keys (all ``[B, ...]``): ``robot_pose`` (x, y, theta), ``robot_velocity`` (v, w of the last
    commanded primitive), ``belief_mean`` ``[B, N, d]`` and ``belief_cov`` ``[B, N, d, d]`` (``d``: the
    filter's model, 4 for the double integrator; the position first), ``belief_velocity`` ``[B, N, 2]``
    (the mean's world-frame velocity, only when the filter's model has one), any state the filter keeps
    beside them, ``logdet_cov`` ``[B, N]``, ``observed`` ``[B, N]``, ``collision``, ``obstacle_polar``
    (distance, bearing of the closest obstacle in view, ``(range, pi)`` when none), ``target_state``
    ``[B, N, D]`` (ground truth, the position first: for evaluation and rendering only). ``reward`` is the
    paper's score increment ``-mean_i log det Sigma_i``; :class:`~aia.transforms.InfoReward` replaces it with
    the shaped reward. Episodes end by truncation
    after ``config.max_steps`` steps.
    """

    batch_locked = True

    def __init__(
        self,
        config: TrackingConfig | None = None,
        batch_size: int | tuple[int] = 1,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        validate_actions: bool = True,
        compile_step: bool = False,
    ) -> None:
        config = config or TrackingConfig()
        num_worlds = _check_batch_size(batch_size)
        super().__init__(device=device, batch_size=torch.Size([num_worlds]))
        self.config = config
        self.validate_actions = validate_actions
        self.num_targets = config.num_targets
        self.dtype = getattr(torch, config.dtype)
        dev, fdt = self.device, self.dtype

        sensing = dict(margin=config.margin, sensor_range=config.sensor.range, fov=math.radians(config.sensor.fov_deg),
                       ray_spacing=config.sensor.obstacle_ray_spacing,
                       collision_supersample=config.collision_supersample, device=dev, dtype=fdt)
        # map=random_obstacles: a new map per world at each of its resets, drawn from its episode key.
        self.map_generator: RandomObstacles | None = None
        self.geometry: Geometry
        if config.map == RANDOM_MAP:
            self.map_generator = RandomObstacles(config.random_map, config.margin)
            size = tuple(float(v) for v in config.random_map.size)
            self.geometry = WorldMapGeometry(num_worlds, size, float(config.random_map.resolution), **sensing)
            self._robot_start, self._map_size = None, size
        else:
            fixed = load_map(config.map)
            self.geometry = map_geometry(config.map, **sensing)
            self._robot_start, self._map_size = fixed.robot_start, (fixed.width, fixed.height)
        self.primitives = motion_primitives(config.robot.linear_speeds, config.robot.angular_speeds, fdt).to(dev)
        self.meas_noise = torch.diag(
            torch.tensor([config.sensor.range_std**2, config.sensor.bearing_std**2], dtype=fdt, device=dev)
        )
        self.meas_std = torch.tensor([config.sensor.range_std, config.sensor.bearing_std], dtype=fdt, device=dev)
        self.targets = make_targets(config, self.geometry)
        self.belief_filter = make_filter(config, self.meas_noise, self.geometry.size)
        # The step's noise draws (rng.slot_keys): per target, the target model's normals, then 2 for the sensor.
        self._step_normals = self.targets.normals + 2
        self._step_slots = rng.slot_keys(2 * math.ceil(self._step_normals * self.num_targets / 2), dev)
        self._advance_fn = compiled(self._advance) if compile_step else self._advance
        self._make_specs()
        self._init_state()
        self.set_seed(seed)

    @property
    def map(self) -> GridMap:
        """The map of every world; with ``map=random_obstacles``, world 0's current one (:meth:`world_map`)."""
        return self.world_map(0)

    def world_map(self, world: int) -> GridMap:
        """World ``world``'s current map (on the CPU)."""
        geometry = self.geometry
        return geometry.grid_map(world) if isinstance(geometry, WorldMapGeometry) else geometry.map

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        B, N, dev, fdt = self.batch_size[0], self.num_targets, self.device, self.dtype
        width, height = self._map_size
        max_v = max(abs(v) for v in self.config.robot.linear_speeds)
        max_w = max(abs(w) for w in self.config.robot.angular_speeds)
        filter_specs = self.belief_filter.specs(B, N, fdt, dev)
        self._filter_keys = tuple(filter_specs)
        self.observation_spec = Composite(
            robot_pose=Bounded(
                low=torch.tensor([0.0, 0.0, -math.pi], dtype=fdt).expand(B, 3),
                high=torch.tensor([width, height, math.pi], dtype=fdt).expand(B, 3),
                shape=(B, 3), dtype=fdt, device=dev,
            ),
            robot_velocity=Bounded(
                low=torch.tensor([-max_v, -max_w], dtype=fdt).expand(B, 2),
                high=torch.tensor([max_v, max_w], dtype=fdt).expand(B, 2),
                shape=(B, 2), dtype=fdt, device=dev,
            ),
            **filter_specs,
            **({"belief_velocity": Unbounded(shape=(B, N, 2), dtype=fdt, device=dev)}
               if self.belief_filter.model.has_velocity else {}),
            logdet_cov=Unbounded(shape=(B, N), dtype=fdt, device=dev),
            observed=Categorical(2, shape=(B, N), dtype=torch.bool, device=dev),
            collision=Categorical(2, shape=(B,), dtype=torch.bool, device=dev),
            obstacle_polar=Bounded(
                low=torch.tensor([0.0, -math.pi], dtype=fdt).expand(B, 2),
                high=torch.tensor([self.config.sensor.range, math.pi], dtype=fdt).expand(B, 2),
                shape=(B, 2), dtype=fdt, device=dev,
            ),
            target_state=Unbounded(shape=(B, N, self.targets.dim), dtype=fdt, device=dev),
            shape=(B,),
            device=dev,
        )
        self.action_spec = Categorical(self.primitives.shape[0], shape=(B,), device=dev)
        self.reward_spec = Unbounded(shape=(B, 1), dtype=fdt, device=dev)
        self.done_spec = Composite(
            done=Categorical(2, shape=(B, 1), dtype=torch.bool, device=dev),
            terminated=Categorical(2, shape=(B, 1), dtype=torch.bool, device=dev),
            truncated=Categorical(2, shape=(B, 1), dtype=torch.bool, device=dev),
            shape=(B,),
            device=dev,
        )

    def _init_state(self) -> None:
        B, dev = self.batch_size[0], self.device
        self.state = self.observation_spec.zero()  # placeholder until the first reset
        self._step_count = torch.zeros(B, dtype=torch.int64, device=dev)
        # On the host: no world has taken more steps since its reset (the max of _step_count, exact after each
        # reset). It tells whether a world can be done (the time limit) without reading the device.
        self._steps_bound = 0
        self._episode = torch.zeros(B, dtype=torch.int64, device=dev)
        self._episode_key = torch.zeros(B, dtype=torch.int64, device=dev)

    def _set_seed(self, seed: int | None) -> None:
        """Key every world's stream from ``seed`` (None: a seed drawn from torch's global generator)."""
        seed = int(torch.randint(0, 2**62, ()).item()) if seed is None else int(seed)
        self._world_key = rng.world_keys(seed, self.batch_size[0], self.device)
        self._episode.zero_()

    def replay_streams(self, seed: int | Sequence[int] | Tensor, worlds: Tensor, episodes: Tensor) -> None:
        """Give world ``b`` the random stream of world ``worlds[b]`` of an env seeded with ``seed`` (one seed,
        or one per world) after ``episodes[b]`` episodes: its next reset starts that world's episode
        ``episodes[b] + 1``.

        One batch can so replay the episodes that several resets of a smaller env would meet (the training
        loop plays several evaluations in one rollout this way), or hold the worlds of several differently
        seeded envs (a population's members). ``worlds`` and ``episodes`` are ``[B]`` integer tensors,
        ``worlds >= 0`` and ``episodes >= 0``.
        """
        B = self.batch_size[0]
        worlds, episodes = torch.as_tensor(worlds), torch.as_tensor(episodes)
        seeds = None if isinstance(seed, int) else torch.as_tensor(seed)
        if seeds is not None and seeds.ndim == 0:
            seeds = seeds.expand(B)
        for name, value in (("worlds", worlds), ("episodes", episodes), ("seed", seeds)):
            if value is None:
                continue
            if value.shape != (B,) or value.dtype.is_floating_point or bool((value < 0).any()):
                raise ValueError(f"{name} must be {B} non-negative integers (one per world), got {value.tolist()}")
        if seeds is None:
            keys = rng.world_keys(int(seed), int(worlds.max()) + 1, self.device)[worlds.to(self.device)]
        else:
            keys = torch.empty(B, dtype=torch.int64, device=self.device)
            for value in seeds.unique().tolist():
                mask = seeds == value
                keys[mask.to(self.device)] = rng.world_keys(value, int(worlds.max()) + 1, self.device)[
                    worlds[mask].to(self.device)]
        self._world_key = keys
        self._episode.copy_(episodes)

    # ------------------------------------------------------------------ reset
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        B = self.batch_size[0]
        mask = None
        if tensordict is not None and "_reset" in tensordict:
            mask = tensordict.get("_reset").reshape(B)
        if mask is None:
            mask = torch.ones(B, dtype=torch.bool, device=self.device)
        self._episode += mask
        self._episode_key = torch.where(mask, rng.episode_keys(self._world_key, self._episode), self._episode_key)
        self._step_count.masked_fill_(mask, 0)
        # a partial reset reads the step counts back (one device sync per reset, not per step)
        self._steps_bound = 0 if tensordict is None or "_reset" not in tensordict else int(self._step_count.max())
        if self.map_generator is not None:
            worlds = mask.nonzero().squeeze(-1)
            self.geometry.draw_maps(worlds, self.map_generator, self._episode_key[worlds])
        fresh = self._initial_state()
        self.state = _select(mask, fresh, self.state)
        out = self.state.clone()
        zeros = torch.zeros(B, 1, dtype=torch.bool, device=self.device)
        out.update({"done": zeros, "terminated": zeros.clone(), "truncated": zeros.clone()})
        return out

    def all_running(self) -> bool:
        """Whether every world is inside its episode: none has reached the time limit (the env's only end of an
        episode), so none is done. Known on the host: asking costs no device sync."""
        return self._steps_bound < self.config.max_steps

    def _initial_state(self) -> TensorDict:
        """A fresh episode for every world (the caller keeps the worlds that are not reset)."""
        cfg, geom = self.config, self.geometry
        B, N, M, dev, fdt = self.batch_size[0], self.num_targets, cfg.target.init_candidates, self.device, self.dtype
        counter = torch.zeros_like(self._step_count)
        u = rng.uniform(self._episode_key, counter, rng.WorldStream.RESET, 4 + N * (4 * M + 3), fdt)
        u_robot, u_heading, u_target, u_belief, u_fallback = torch.split(u, (3, 1, 2 * N * M, 2 * N * M, 3 * N), -1)

        if self._robot_start is not None:
            robot_xy = torch.tensor(self._robot_start, dtype=fdt, device=dev).expand(B, 2)
        else:
            robot_xy = geom.sample_free(u_robot)
        heading = (2 * u_heading - 1) * math.pi
        pose = torch.cat((robot_xy, heading), -1)
        target_xy, belief_xy = self._placements(robot_xy, u_target.reshape(B, N, M, 2), u_belief.reshape(B, N, M, 2),
                                                u_fallback.reshape(B, N, 3))
        # Headings, for the models that have one: each point faces away from what it was placed around, as
        # ttenv's placement turns them (derived, not drawn: the placements' draws stay as they were).
        anchor_of_target = belief_xy if cfg.belief.init_anchor == "robot" else robot_xy[:, None, :]
        anchor_of_belief = robot_xy[:, None, :] if cfg.belief.init_anchor == "robot" else target_xy
        target_heading = _direction(target_xy - anchor_of_target)
        belief_heading = _direction(belief_xy - anchor_of_belief)

        model = self.belief_filter.model
        beliefs = self.belief_filter.initial(model.initial_mean(belief_xy, belief_heading), cfg.belief.init_cov,
                                             self._episode_key, counter)
        return TensorDict(
            robot_pose=pose,
            robot_velocity=torch.zeros(B, 2, dtype=fdt, device=dev),
            **beliefs,
            **self._belief_velocity(beliefs["belief_mean"]),
            logdet_cov=belief.logdet(beliefs["belief_cov"]),
            observed=torch.zeros(B, N, dtype=torch.bool, device=dev),
            collision=torch.zeros(B, dtype=torch.bool, device=dev),
            obstacle_polar=geom.closest_obstacle(pose),
            target_state=self.targets.initial(target_xy, target_heading),
            batch_size=self.batch_size,
            device=dev,
        )

    def _placements(self, robot_xy: Tensor, u_first: Tensor, u_second: Tensor, u_fallback: Tensor
                    ) -> tuple[Tensor, Tensor]:
        """``(target_xy, belief_xy)`` ``[B, N, 2]``, each the first collision-free of ``M`` candidates.

        ``belief.init_anchor="target"``: the target at ``target.init_distance`` from the robot at a uniform
        angle, the belief mean offset from it in a disk or a box. ``"robot"`` (ttenv): the belief mean at
        ``belief.init_distance`` from the robot, the target within ``belief.init_offset`` of the mean and
        ``belief.init_offset_angle`` of the direction from the robot to the mean.
        """
        cfg, geom = self.config, self.geometry
        fallback = geom.sample_free(u_fallback)
        size = cfg.belief.init_offset
        if cfg.belief.init_anchor == "robot":
            lo, hi = cfg.belief.init_distance
            offset = _polar_offset(lo + (hi - lo) * u_first[..., 0], u_first[..., 1])
            belief_xy = _first_free(robot_xy[:, None, None, :] + offset, geom, fallback)
            away = _direction(belief_xy - robot_xy[:, None, :]).unsqueeze(-1)
            angle = away + (2 * u_second[..., 1] - 1) * cfg.belief.init_offset_angle
            distance = size * u_second[..., 0]
            offset = torch.stack((distance * torch.cos(angle), distance * torch.sin(angle)), -1)
            return _first_free(belief_xy[:, :, None, :] + offset, geom, belief_xy), belief_xy
        lo, hi = cfg.target.init_distance
        offset = _polar_offset(lo + (hi - lo) * u_first[..., 0], u_first[..., 1])
        target_xy = _first_free(robot_xy[:, None, None, :] + offset, geom, fallback)
        if cfg.belief.init_offset_shape == "disk":
            offset = _polar_offset(size * u_second[..., 0], u_second[..., 1])
        else:
            offset = (2 * u_second - 1) * size
        return target_xy, _first_free(target_xy[:, :, None, :] + offset, geom, target_xy)

    def _belief_velocity(self, mean: Tensor) -> dict[str, Tensor]:
        """``{"belief_velocity": [B, N, 2]}`` when the filter's model has a velocity, else nothing."""
        model = self.belief_filter.model
        return {"belief_velocity": model.velocity(mean)} if model.has_velocity else {}

    # ------------------------------------------------------------------- step
    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action")
        if self.validate_actions:
            _check_actions(action, self.primitives.shape[0])
        self._step_count += 1
        self._steps_bound += 1
        fields, reward, truncated = self._advance_fn(dict(self.state.items()), action, self._episode_key,
                                                     self._step_count)
        # The kernel's outputs have the right batch size and device: skip TensorDict's per-entry checks
        # (a quarter of the TorchRL-side cost of a step at B = 1).
        self.state = TensorDict._new_unsafe(fields, batch_size=self.batch_size, device=self.device)
        fields = dict(fields, reward=reward, done=truncated, terminated=torch.zeros_like(truncated),
                      truncated=truncated)
        return TensorDict._new_unsafe(fields, batch_size=self.batch_size, device=self.device)

    def _advance(self, state: dict[str, Tensor], action: Tensor, key: Tensor, step: Tensor
                 ) -> tuple[dict[str, Tensor], Tensor, Tensor]:
        """One step of every world as a pure function of tensors (compiled when ``compile_step=True``).

        Returns the new state (every key of the observation spec), the raw reward (the score increment
        ``-mean_i log det Sigma_i``, ``[B, 1]``) and the truncation flags (``[B, 1]``).
        """
        cfg, geom = self.config, self.geometry
        N, pose, targets = self.num_targets, state["robot_pose"], state["target_state"]
        noise = rng.normal(key, step, rng.WorldStream.STEP, self._step_normals * N, self.dtype, self._step_slots)
        noise = noise.unflatten(-1, (N, self._step_normals))

        # Robot: a colliding move (or, in the 2019 rule, one too close to the targets) keeps the position;
        # the heading turns either way.
        velocity = self.primitives[action]
        proposal = se2_step(pose, velocity, cfg.dt)
        collision = geom.in_collision(proposal[:, :2])
        blocked = collision
        if cfg.robot.target_margin > 0:
            spread = (proposal[:, None, :2] - targets[..., :2]).square().sum((-1, -2))
            blocked = blocked | (spread < cfg.robot.target_margin**2)
        pose = torch.cat((torch.where(blocked[:, None], pose[:, :2], proposal[:, :2]), proposal[:, 2:]), -1)

        targets = self.targets.step(targets, noise[..., :-2], pose)

        # Sensor: range, field of view and line of sight to the true targets.
        observed, polar = geom.in_view(pose, targets[..., :2])
        measurement = polar + noise[..., -2:] * self.meas_std

        # Belief: the filter predicts all and updates the observed ones (SPEC 5 order).
        beliefs = self.belief_filter.step(
            {k: state[k] for k in self._filter_keys}, measurement, observed, pose, key, step)
        logdet = belief.logdet(beliefs["belief_cov"])
        # the last closest obstacle: where a geometry that walks its rays looks first
        obstacle_polar = geom.closest_obstacle(pose, (state["robot_pose"], state["obstacle_polar"]))
        fields = dict(robot_pose=pose, robot_velocity=velocity, **beliefs,
                      **self._belief_velocity(beliefs["belief_mean"]), logdet_cov=logdet, observed=observed,
                      collision=collision, obstacle_polar=obstacle_polar, target_state=targets)
        reward = -logdet.mean(-1, keepdim=True)
        truncated = (step >= cfg.max_steps).unsqueeze(-1)
        return fields, reward, truncated


def make_targets(config: TrackingConfig, geometry: Geometry) -> TargetModel:
    """The true targets' model of a setting (``env.target.model``)."""
    t, dt = config.target, config.dt
    if t.model in ("double_integrator", "evasive"):
        options = dict(collision_rule=t.collision_rule, detour_margin=t.detour_margin, detour_speed=t.detour_speed,
                       detour_floor=max(config.margin, 1e-6))
        if t.model == "evasive":
            flee_range = config.sensor.range if t.flee_range is None else t.flee_range
            return EvasiveTargets(geometry, dt, t.q, t.reflect_gain, t.reflect_noise_std, t.speed_limit,
                                  flee_range=flee_range, flee_accel=t.flee_accel, **options)
        return DoubleIntegratorTargets(geometry, dt, t.q, t.reflect_gain, t.reflect_noise_std, t.speed_limit,
                                       **options)
    v_max = math.inf if t.speed_limit is None else t.speed_limit
    w_max = math.inf if t.angular_speed_limit is None else t.angular_speed_limit
    if t.model == "se2_sine":
        return SineTargets(geometry, dt, t.sine_step, t.sine_frequency, t.sine_amplitude, v_max, w_max,
                           t.turn_on_collision)
    return ConstantSpeedTargets(geometry, dt, t.q, v_max, w_max)


def make_filter(config: TrackingConfig, meas_noise: Tensor, map_size: Tensor) -> BeliefFilter:
    """The belief filter of a setting (``env.belief.filter`` over ``env.belief.model``)."""
    b = config.belief
    q = config.target.q if b.q is None else b.q
    model = belief_model(belief_model_name(config), config.dt, q, b.control, meas_noise.device, meas_noise.dtype)
    options = dict(log_det_cap=math.log(b.det_cap) if b.det_cap is not None else math.inf, map_size=map_size,
                   clip_to_map=b.clip_to_map, speed_clip=b.speed_clip)
    if b.filter == "ukf":
        options["kappa"] = b.ukf_kappa
    if b.filter == "particle":
        options.update(num_targets=config.num_targets, particles=b.particles,
                       resample_threshold=b.resample_threshold, roughening=b.roughening)
    return FILTERS[b.filter](model, meas_noise, **options)


# ---------------------------------------------------------------------- helpers
def _check_batch_size(batch_size: int | tuple[int] | torch.Size) -> int:
    shape = (batch_size,) if isinstance(batch_size, int) else tuple(batch_size)
    if len(shape) != 1 or not isinstance(shape[0], int) or shape[0] < 1:
        raise ValueError(f"batch_size={batch_size!r} must be a positive int B (or (B,)), the number of worlds")
    return shape[0]


def _check_actions(action: Tensor, num_actions: int) -> None:
    if action.dtype.is_floating_point or action.dtype == torch.bool:
        raise ValueError(f"action must hold integer indices in [0, {num_actions - 1}], got dtype {action.dtype}")
    bad = (action < 0) | (action >= num_actions)
    if action.device.type != "cpu":  # checked on the device: reading the flag back would sync every step
        torch._assert_async(~bad.any(), f"an action is out of range: allowed indices are 0..{num_actions - 1}")
    elif bad.any():
        raise ValueError(
            f"action {action[bad][0].item()} is out of range: allowed indices are 0..{num_actions - 1} "
            f"(motion primitive a = 3 * i_v + i_w)"
        )


def _polar_offset(distance: Tensor, u_angle: Tensor) -> Tensor:
    angle = (2 * u_angle - 1) * math.pi
    return torch.stack((distance * torch.cos(angle), distance * torch.sin(angle)), -1)


def _direction(delta: Tensor) -> Tensor:
    """The angle of each vector ``[..., 2]``."""
    return torch.atan2(delta[..., 1], delta[..., 0])


def _first_free(candidates: Tensor, geometry: Geometry, fallback: Tensor) -> Tensor:
    """The first candidate ``[..., M, 2]`` of each row where an episode may start (collision-free; in the start
    cells of a random map), or ``fallback`` if there is none."""
    free = geometry.free_start(candidates)
    first = free.to(torch.int8).argmax(-1, keepdim=True)
    chosen = torch.gather(candidates, -2, first.unsqueeze(-1).expand(*first.shape, 2)).squeeze(-2)
    return torch.where(free.any(-1, keepdim=True), chosen, fallback)


def _select(mask: Tensor, new: TensorDict, old: TensorDict) -> TensorDict:
    """Entries of ``new`` for the worlds in ``mask``, of ``old`` for the others."""
    return new.apply(lambda n, o: torch.where(mask.reshape(-1, *([1] * (n.ndim - 1))), n, o), old)
