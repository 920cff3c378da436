"""``SceneRecorder``: a TorchRL transform that writes the Foxglove scene of every step of chosen episodes."""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.envs.transforms import Transform

from aia.envs.tracking import TargetTrackingEnv
from aia.logging import schemas
from aia.logging.mcap_logger import MCAPLogger
from aia.logging.scenes import (
    PARTICLES_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    WORLD_TOPIC,
    FrameEncoder,
    WorldInfo,
    particle_cloud_message,
    world_message,
)

_KEYS = ("robot_pose", "target_state", "belief_mean", "belief_cov", "observed")
_PARTICLE_KEYS = ("belief_particles", "belief_weights")  # a particle filter's belief (aia.envs.filters.particle)


class SceneRecorder(Transform):
    """Record one world of a tracking env into an :class:`MCAPLogger` as Foxglove scenes.

    The recorder is idle until :meth:`record` arms it; the next reset then writes the map (``/world``) and
    the first scene, every step writes ``/tf`` and ``/scene`` (:mod:`aia.logging.scenes`), and the episode
    of world ``world`` ending disarms it, and with a particle filter every step writes the particles too
    (``/belief_particles``). It reads the env's raw keys (robot pose, true targets, belief) and changes nothing in
    the tensordict, so it can sit anywhere in the env's transforms.

    Args:
        logger: where the scenes go.
        world: index of the recorded world in the env's batch.
        sigma: the belief ellipses are drawn at this many standard deviations.
    """

    def __init__(self, logger: MCAPLogger, world: int = 0, sigma: float = 2.0) -> None:
        super().__init__(in_keys=list(_KEYS), out_keys=[])
        if world < 0:
            raise ValueError(f"world={world} must be >= 0")
        self.logger = logger
        self.world = world
        self.sigma = sigma
        self._armed: tuple[int, int] | None = None      # (episode, frame) of the next episode to record
        self._recording: tuple[int, int] | None = None  # (episode, frame) of the episode being recorded
        self._step_index = 0
        self._encoder: FrameEncoder | None = None

    @property
    def recording(self) -> bool:
        """Whether an episode is being written now."""
        return self._recording is not None

    def record(self, episode: int, frame: int) -> None:
        """Record the next episode of the world, labelled with ``episode`` and the training ``frame``."""
        self._armed = (episode, frame)

    def _tracking_env(self) -> TargetTrackingEnv:
        """The recorded env, checked: a tracking env that has the recorded world."""
        env = self.parent.base_env if self.parent is not None else None
        if not isinstance(env, TargetTrackingEnv):
            raise RuntimeError("SceneRecorder must be a transform of a TargetTrackingEnv")
        if self.world >= env.batch_size[0]:
            raise ValueError(f"world={self.world} is out of range for an env of {env.batch_size[0]} worlds")
        return env

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        if self._armed is None:
            return tensordict_reset
        env = self._tracking_env()
        reset_mask = tensordict.get("_reset", None) if tensordict is not None else None
        if reset_mask is not None and not bool(reset_mask.reshape(-1)[self.world]):
            return tensordict_reset  # a partial reset that leaves the recorded world alone
        self._recording, self._armed, self._step_index = self._armed, None, 0
        sensor = env.config.sensor
        self._encoder = FrameEncoder(sensor.range, sensor.fov_deg, self.sigma)
        info = WorldInfo(env.world_map(self.world), sensor.range, sensor.fov_deg, env.num_targets, *self._recording)
        run = self.logger.experiment
        stamp = run.now()
        run.write(run.channel(WORLD_TOPIC, schemas.SCENE_UPDATE), world_message(info, stamp), stamp)
        self._write_frame(tensordict_reset, stamp)
        return tensordict_reset

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self._recording is not None:
            self._step_index += 1
            self._write_frame(next_tensordict, self.logger.experiment.now())
            if bool(next_tensordict.get("done").reshape(-1)[self.world]):
                self._recording = None
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Outside an env (a replay buffer, a stored rollout): write the step if recording, pass it on."""
        return self._call(tensordict)

    def _write_frame(self, tensordict: TensorDictBase, stamp: int) -> None:
        pose, targets, mean, cov, observed = (tensordict.get(key)[self.world].tolist() for key in _KEYS)
        episode, frame = self._recording
        time = self._step_index * self.parent.base_env.config.dt
        tf, scene = self._encoder.encode(stamp, episode, frame, self._step_index, time, pose, targets, mean, cov,
                                         observed)
        run = self.logger.experiment
        run.write(run.channel(TF_TOPIC, schemas.FRAME_TRANSFORM), tf, stamp)
        run.write(run.channel(SCENE_TOPIC, schemas.SCENE_UPDATE), scene, stamp)
        if _PARTICLE_KEYS[0] in tensordict.keys():  # noqa: SIM118 (a TensorDict has no `in`)
            particles, weights = (tensordict.get(key)[self.world].cpu().numpy() for key in _PARTICLE_KEYS)
            run.write(run.channel(PARTICLES_TOPIC, schemas.POINT_CLOUD), particle_cloud_message(
                stamp, particles, weights), stamp)
