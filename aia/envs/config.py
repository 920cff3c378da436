"""Typed configuration of the tracking env, its features and its reward.

The dataclasses hold the defaults of docs/spec.md (the paper's text where the paper and the authors' 2019 code
differ, and the 2019 reward); the Hydra presets in ``conf/env/`` override only what a setting changes.
The schema is registered with Hydra's ConfigStore as the root config ``env_schema`` (each preset lists
``/env_schema@_here_`` first), so that every preset is type-checked and a misspelt field fails with its
name, and ``env=`` offers the settings only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from aia.config.checks import check_choice, check_number, require
from aia.config.composing import node_error

# The names the env's fields choose among, here and not beside their torch code (which imports them from here), so
# that the schema and its checks load without torch: the apps' --help and refusals answer in about half a second.
TARGET_MODELS = ("double_integrator", "evasive", "se2_sine", "se2_constant")  # aia.envs.targets
BELIEF_MODELS = ("double_integrator", "se2", "se2_velocity")  # aia.envs.belief_models
CONTROLS = ("zero", "random")  # the control an se2 belief model assumes (aia.envs.belief_models)
FILTER_NAMES = ("kf", "ukf", "particle")  # aia.envs.filters.FILTERS, in this order
RANDOM_MAP = "random_obstacles"  # env.map's name for a new random layout per world and episode (map_generator)
RANDOM_SHAPES = ("box", "l", "t")  # the shapes of its obstacles


@dataclass
class RobotConfig:
    """SE(2) robot driven by motion primitives (SPEC 2)."""

    linear_speeds: list[float] = field(default_factory=lambda: [3.0, 2.0, 1.0, 0.0])
    angular_speeds: list[float] = field(default_factory=lambda: [math.pi / 2, 0.0, -math.pi / 2])
    # 2019 code: the robot keeps its position when sqrt(sum_k |p - t_k|^2) < target_margin (0 disables).
    target_margin: float = 0.0


@dataclass
class TargetConfig:
    """The true targets (SPEC 3; the models of aia.envs.targets)."""

    # "double_integrator" (SPEC 3), "evasive" (a double integrator that flees the robot), "se2_sine" (ttenv v2)
    # or "se2_constant" (ttenv v3).
    model: str = "double_integrator"
    # double_integrator: process noise; se2_constant: the noise of its speeds' random walk.
    q: float = 0.01
    # None: no limit on the true target's speed (2019 code); a number rescales the velocity to that norm
    # (double_integrator) or clips the linear speed (the se2 models).
    speed_limit: Optional[float] = None
    # se2 models: the angular speed is clipped to +-this (None: no limit).
    angular_speed_limit: Optional[float] = None
    # se2_sine: the curve y = amplitude sin(frequency x), followed step_length further each step; a blocked
    # target starts a new curve turned by U(-turn_on_collision, turn_on_collision).
    sine_step: float = 0.1
    sine_frequency: float = 0.5
    sine_amplitude: float = 5.0
    turn_on_collision: float = math.pi / 4
    # double_integrator: what a colliding move does. "reflect" (2019): the target keeps its position and its
    # velocity becomes reflect_gain * v + N(0, reflect_noise_std^2). "detour" (ttenv v1): it keeps its position
    # and leaves away from the nearest obstacle, and every step it is pushed away from the obstacle it heads
    # into, by (|v| cos beta)+ / max(margin, d - detour_margin) (aia.envs.targets).
    collision_rule: str = "reflect"
    reflect_gain: float = -0.4
    reflect_noise_std: float = 0.2
    detour_margin: float = 3.5
    # The speed at which the push turns 3/4 of a half turn from the obstacle's direction.
    detour_speed: float = 1.75
    # evasive: while the robot is within flee_range (None: the sensor's range) the target accelerates at
    # flee_accel (m/s^2) straight away from it.
    flee_range: Optional[float] = None
    flee_accel: float = 1.0
    # Initial distance from the robot, uniform in [min, max] at a uniform angle (2019 code: exactly 8 m).
    init_distance: list[float] = field(default_factory=lambda: [0.0, 8.0])
    # Collision-free placements are drawn from this many candidates before falling back to a free cell.
    init_candidates: int = 32


@dataclass
class SensorConfig:
    """Range-bearing sensor with field of view and occlusion (SPEC 4)."""

    range: float = 10.0
    fov_deg: float = 120.0
    range_std: float = 0.2
    bearing_std: float = 0.01
    # Angular spacing of the rays that find the closest obstacle in the field of view (2019 code: 0.05 rad).
    obstacle_ray_spacing: float = 0.05


@dataclass
class BeliefConfig:
    """Per-target belief filter (SPEC 5; aia.envs.filters)."""

    # "kf" (SPEC 5's extended Kalman filter; double_integrator model only), "ukf" (unscented) or "particle"
    # (bootstrap particle filter, aia.envs.filters.particle).
    filter: str = "kf"
    # The motion model the filter assumes (aia.envs.belief_models): "double_integrator", "se2" or
    # "se2_velocity"; None: the true targets' own (se2_sine -> se2, se2_constant -> se2_velocity).
    model: Optional[str] = None
    # se2 model: the unknown target control the filter assumes, "zero" or "random" (ttenv's draw).
    control: str = "zero"
    # ukf: Julier's sigma-point spread kappa (ttenv: 1).
    ukf_kappa: float = 1.0
    # particle: particles per target; resampled (systematic) below resample_threshold * particles effective
    # particles, then roughened by roughening * spread * particles^(-1/d) per entry.
    particles: int = 256
    resample_threshold: float = 0.5
    roughening: float = 0.2
    # Process noise the filter assumes; None: the targets' true q.
    q: Optional[float] = None
    init_cov: float = 30.0
    # Where an episode's beliefs and targets start. "target": the target at target.init_distance from the
    # robot, the belief mean offset from it by init_offset_shape / init_offset. "robot" (ttenv): the belief
    # mean at init_distance from the robot, the target within init_offset of it and init_offset_angle of the
    # direction from the robot to the belief.
    init_anchor: str = "target"
    init_distance: list[float] = field(default_factory=lambda: [5.0, 20.0])
    init_offset_angle: float = math.pi
    # Initial mean offset from the true target: "disk" (distance uniform in [0, size]) or "box" (+-size).
    init_offset_shape: str = "disk"
    init_offset: float = 5.0
    # Keep the previous covariance when the new one has det >= det_cap (2019 code: 1e6). None disables.
    # On by default: every score of the paper was produced with it (see docs/environment.md).
    det_cap: Optional[float] = 1.0e6
    # 2019 code: clip the mean to the map bounds and each velocity component to +-speed_clip.
    clip_to_map: bool = False
    speed_clip: Optional[float] = None


@dataclass
class FeatureConfig:
    """The belief-feature transform (SPEC 6)."""

    # "exact": radial and angular rates of the belief mean seen from the moving robot;
    # "2019": the authors' 2019 formula (angular rate about the map origin, an extra |p| w term).
    relative_velocity: str = "exact"
    # ttenv's map image under the observation key "local_map" (aia.transforms.LocalMap): "none", "occupancy"
    # (TargetTracking-v4: the occupancy in front of the robot, 1 channel) or "occupancy_visits" (v5: and the
    # visit frequencies left, right, in front of and behind that square, 5 channels).
    local_map: str = "none"
    # The image's side in map cells (ttenv: 28).
    im_size: int = 28


# features.local_map's layouts, and the channels of each.
LOCAL_MAP_CHANNELS = {"none": 0, "occupancy": 1, "occupancy_visits": 5}


@dataclass
class RewardConfig:
    """The reward transform (SPEC 7); defaults are the 2019 code's form, which produced the paper's runs."""

    kappa_m: float = 0.1
    # "mean" (2019 code) or "sum" (the paper's formula) of log det over targets.
    target_aggregate: str = "mean"
    kappa_d: float = 0.1
    kappa_o: float = 1.0
    # "2019": kappa_o * m^2 / max(m^2, o_r^2) with m = obstacle_margin; "paper": kappa_o / o_r^2.
    obstacle_form: str = "2019"
    obstacle_margin: float = 0.5
    observed_bonus: float = 1.0
    # Later rewrite: R <- min(0, R) - collision_penalty on a collision (0 disables).
    collision_penalty: float = 0.0


@dataclass
class RandomMapConfig:
    """``map: random_obstacles``: a new obstacle layout per world and episode (aia.envs.map_generator)."""

    # The map: [width, height] in metres, a whole number of resolution-sized cells (default: obstacles4's).
    size: list[float] = field(default_factory=lambda: [36.2, 36.2])
    resolution: float = 0.2
    # Obstacles per layout, uniform in [min, max]; each one of shapes ("box", "l", "t"), its rectangles'
    # lengths and widths uniform in [min, max] metres, turned by a uniform angle in +-rotation_deg.
    num_obstacles: list[int] = field(default_factory=lambda: [4, 8])
    shapes: list[str] = field(default_factory=lambda: ["box", "l", "t"])
    length: list[float] = field(default_factory=lambda: [2.0, 8.0])
    width: list[float] = field(default_factory=lambda: [0.6, 2.0])
    rotation_deg: float = 180.0
    # A layout whose connected start cells cover less than this fraction of the map is drawn again, up to
    # attempts times (then the reset fails with a one-line error).
    min_start_area: float = 0.25
    attempts: int = 8


@dataclass
class TrackingConfig:
    """One tracking setting: world, robot, targets, sensor, belief, features and reward."""

    # A map of conf/maps by name, a map .yaml by path, or "random_obstacles" (random_map's layouts).
    map: str = "empty"
    num_targets: int = 1
    max_steps: int = 100
    dt: float = 0.5
    # margin2wall: a position within this distance of the bounds or an occupied cell collides.
    margin: float = 0.5
    # The collision grid is this many times finer than the map grid.
    collision_supersample: int = 4
    dtype: str = "float32"
    robot: RobotConfig = field(default_factory=RobotConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    belief: BeliefConfig = field(default_factory=BeliefConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    random_map: RandomMapConfig = field(default_factory=RandomMapConfig)

    def __post_init__(self) -> None:
        validate(self)


_CHOICES = {
    "target.model": TARGET_MODELS,
    "target.collision_rule": ("reflect", "detour"),
    "belief.filter": FILTER_NAMES,
    "belief.control": CONTROLS,
    "belief.init_anchor": ("target", "robot"),
    "belief.init_offset_shape": ("disk", "box"),
    "features.relative_velocity": ("exact", "2019"),
    "features.local_map": tuple(LOCAL_MAP_CHANNELS),
    "reward.target_aggregate": ("mean", "sum"),
    "reward.obstacle_form": ("2019", "paper"),
    "dtype": ("float32", "float64"),
}

_POSITIVE_INTEGERS = ("num_targets", "max_steps", "collision_supersample", "target.init_candidates",
                      "belief.particles", "features.im_size")
_POSITIVE = ("dt", "sensor.range", "sensor.range_std", "sensor.bearing_std", "sensor.obstacle_ray_spacing",
             "belief.init_cov", "target.sine_step", "belief.ukf_kappa")
_NON_NEGATIVE = ("margin", "target.q", "target.reflect_noise_std", "robot.target_margin", "belief.init_offset",
                 "reward.obstacle_margin", "reward.collision_penalty", "target.turn_on_collision",
                 "target.detour_margin", "belief.init_offset_angle", "belief.roughening", "target.flee_accel")
_NUMBERS = ("target.reflect_gain", "target.sine_frequency", "target.sine_amplitude", "target.detour_speed",
            "reward.kappa_m", "reward.kappa_d", "reward.kappa_o", "reward.observed_bonus")
_POSITIVE_OR_NULL = ("belief.det_cap", "belief.speed_clip", "target.speed_limit", "target.angular_speed_limit",
                     "target.flee_range")
# The filter's model when belief.model is null: the true targets' own.
DEFAULT_BELIEF_MODEL = {"double_integrator": "double_integrator", "evasive": "double_integrator", "se2_sine": "se2",
                        "se2_constant": "se2_velocity"}


def _get(cfg: TrackingConfig, dotted: str):
    value = cfg
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def belief_model_name(cfg: TrackingConfig) -> str:
    """The motion model the setting's filter assumes: ``belief.model``, or the true targets' own."""
    return cfg.belief.model or DEFAULT_BELIEF_MODEL[cfg.target.model]


def validate(cfg: TrackingConfig) -> None:
    """Raise :class:`~aia.config.errors.ConfigError` naming the first field (``env.<field>``) whose value is out of
    its allowed set or range, or the map file and field that is wrong (the map is loaded and checked here, last: a
    map loads torch)."""
    for name, allowed in _CHOICES.items():
        check_choice(f"env.{name}", _get(cfg, name), allowed)
    for name in _POSITIVE_INTEGERS:
        check_number(f"env.{name}", _get(cfg, name), ge=1, integer=True)
    for name in _POSITIVE:
        check_number(f"env.{name}", _get(cfg, name), gt=0)
    for name in _NON_NEGATIVE:
        check_number(f"env.{name}", _get(cfg, name), ge=0)
    for name in _NUMBERS:
        check_number(f"env.{name}", _get(cfg, name))
    for name in _POSITIVE_OR_NULL:
        check_number(f"env.{name}", _get(cfg, name), gt=0, optional=True)
    check_number("env.belief.q", cfg.belief.q, ge=0, optional=True)
    check_number("env.sensor.fov_deg", cfg.sensor.fov_deg, gt=0, le=360)
    check_number("env.belief.resample_threshold", cfg.belief.resample_threshold, gt=0, le=1)
    for name in ("target.init_distance", "belief.init_distance"):
        distance = list(_get(cfg, name))
        require(len(distance) == 2 and all(isinstance(d, (int, float)) for d in distance)
                and 0 <= distance[0] <= distance[1], f"env.{name}", distance, "[min, max] with 0 <= min <= max")
    check_choice("env.belief.model", cfg.belief.model, (None, *BELIEF_MODELS))
    require(cfg.belief.filter != "kf" or belief_model_name(cfg) == "double_integrator", "env.belief.filter",
            cfg.belief.filter, f"ukf or particle with belief.model={belief_model_name(cfg)} (kf takes the linear "
            "double_integrator model only)")
    for name in ("robot.linear_speeds", "robot.angular_speeds"):
        speeds = list(_get(cfg, name))
        require(len(speeds) > 0 and all(isinstance(v, (int, float)) for v in speeds), f"env.{name}", speeds,
                "a non-empty list of numbers")
    validate_random_map(cfg)
    if cfg.map != RANDOM_MAP:
        from aia.envs.maps import check_start_margin, load_map

        check_start_margin(load_map(cfg.map), cfg.margin)


def validate_random_map(cfg: TrackingConfig) -> None:
    """The ``random_map`` fields, and what a generated map cannot do (ttenv v1's detour rule needs a fixed map)."""
    m = cfg.random_map
    size = list(m.size)
    require(len(size) == 2 and all(isinstance(v, (int, float)) and v > 0 for v in size), "env.random_map.size",
            size, "[width, height] in metres, both > 0")
    check_number("env.random_map.resolution", m.resolution, gt=0)
    whole = all(math.isclose(round(v / m.resolution) * m.resolution, v, abs_tol=1e-6) for v in size)
    require(whole, "env.random_map.size", size, f"a whole number of {m.resolution} m cells (random_map.resolution)")
    free = min(size) - 2 * math.ceil(cfg.margin / m.resolution) * m.resolution
    require(free > 0, "env.random_map.size", size, f"a map wider than twice env.margin={cfg.margin} m")
    for name, low in (("num_obstacles", 0), ("length", None), ("width", None)):
        bounds = list(getattr(m, name))
        integer = name == "num_obstacles"
        ok = len(bounds) == 2 and all(isinstance(v, int if integer else (int, float)) for v in bounds)
        ok = ok and bounds[0] <= bounds[1] and (bounds[0] >= low if integer else bounds[0] > 0)
        allowed = "[min, max] integers with 0 <= min <= max" if integer else "[min, max] in metres with 0 < min <= max"
        require(ok, f"env.random_map.{name}", bounds, allowed)
    shapes = list(m.shapes)
    require(len(shapes) > 0 and set(shapes) <= set(RANDOM_SHAPES), "env.random_map.shapes", shapes,
            f"a non-empty list among {list(RANDOM_SHAPES)}")
    check_number("env.random_map.rotation_deg", m.rotation_deg, ge=0, le=180)
    check_number("env.random_map.min_start_area", m.min_start_area, gt=0, le=1)
    check_number("env.random_map.attempts", m.attempts, ge=1, integer=True)
    require(cfg.map != RANDOM_MAP or cfg.target.collision_rule != "detour", "env.target.collision_rule",
            cfg.target.collision_rule, f"reflect with map={RANDOM_MAP} (the detour rule's nearest-obstacle table "
            "is built per fixed map)")


def to_tracking_config(cfg: DictConfig | TrackingConfig) -> TrackingConfig:
    """A validated :class:`TrackingConfig` from a composed ``env`` node (or the config itself); a
    :class:`~aia.config.errors.ConfigError` names the first bad field."""
    if isinstance(cfg, TrackingConfig):
        return cfg
    try:
        merged = OmegaConf.merge(OmegaConf.structured(TrackingConfig), cfg)
        return OmegaConf.to_object(merged)
    except OmegaConfBaseException as err:
        raise node_error(err, cfg, TrackingConfig, "env.") from None


# A root config, not a member of the env group: `env=<name>` offers only the settings. Presets start with
# `- /env_schema@_here_` in their defaults.
ConfigStore.instance().store(name="env_schema", node=TrackingConfig)
