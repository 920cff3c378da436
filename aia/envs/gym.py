"""``TargetTrackingGymEnv``: one tracking world behind the Gymnasium API (numpy in, numpy out).

The env wraps :func:`aia.envs.factory.make_env` with ``batch_size=1`` and the feature and reward
transforms, so an observation is the ``6N + 2`` feature vector of SPEC 6 (float32) and a reward is the
shaped reward of SPEC 7. A setting with a map observation (``env.features.local_map``, the ttenv v4/v5
presets) has a ``Dict`` observation space instead: ``{"observation": the features, "local_map": the
[C, H, W] image in [-1, 1]}``. The paper's score increment ``-mean_i log det Sigma_i`` and the raw per-target
quantities come in ``info``. ``import aia`` registers the id ``"aia/TargetTracking-v0"``::

    import aia, gymnasium
    env = gymnasium.make("aia/TargetTracking-v0", map="empty", num_targets=1, render_mode="rgb_array")
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict, TensorDictBase

from aia.envs.factory import make_env
from aia.envs.render import render_frame
from aia.modules.q_networks import MAP_KEY, OBSERVATION_KEY

# (map, number of targets) of the four paper settings.
_PAPER_SETTINGS = {
    ("empty", 1): "empty1",
    ("obstacles4", 1): "obstacles1",
    ("empty_small", 2): "small2",
    ("empty_small", 3): "small3",
}
# Number of targets when only the map is given: that of the map's first paper setting (else 1).
_DEFAULT_TARGETS = {"empty": 1, "obstacles4": 1, "empty_small": 2}


def resolve_setting(
    setting: str | None, map: str | None, num_targets: int | None, overrides: Sequence[str] = ()
) -> tuple[str, list[str]]:
    """The preset name and the overrides that build the env for ``(setting, map, num_targets)``.

    With ``setting`` given, ``map`` and ``num_targets`` (when not None) override its fields. Without it,
    ``(map, num_targets)`` picks a paper setting (``empty``/1 -> ``empty1``, ``obstacles4``/1 ->
    ``obstacles1``, ``empty_small``/2 -> ``small2``, ``empty_small``/3 -> ``small3``); any other pair
    builds on ``empty1`` with ``map=`` and ``num_targets=`` overrides (and ``max_steps=150`` for several
    targets, as in the multi-target paper settings). The user's ``overrides`` come last and win.
    """
    overrides = list(overrides)
    if setting is not None:
        extra = [] if map is None else [f"map={map}"]
        extra += [] if num_targets is None else [f"num_targets={int(num_targets)}"]
        return setting, extra + overrides
    map = "empty" if map is None else map
    num_targets = _DEFAULT_TARGETS.get(map, 1) if num_targets is None else int(num_targets)
    paper = _PAPER_SETTINGS.get((map, num_targets))
    if paper is not None:
        return paper, overrides
    extra = [f"map={map}", f"num_targets={num_targets}"]
    if num_targets > 1:
        extra.append("max_steps=150")
    return "empty1", extra + overrides


class TargetTrackingGymEnv(gymnasium.Env):
    """A single tracking world with the Gymnasium API.

    Args:
        setting: an env preset (``"empty1"``, ``"obstacles1"``, ``"small2"``, ``"small3"``, ``*_2019``).
        map: a map name (``"empty"``, ``"empty_small"``, ``"obstacles4"``) or a map YAML path.
        num_targets: number of targets.
        render_mode: ``None`` or ``"rgb_array"``.
        overrides: Hydra-style dotted overrides of the setting's fields (``"sensor.range=12"``).
        device: where the torch env runs.
        render_size: side of the rendered frames in pixels.

    See :func:`resolve_setting` for how ``setting``, ``map`` and ``num_targets`` combine. ``step`` returns
    ``info`` with ``logdet_cov`` (``[N]``), ``observed`` (``[N]`` bool), ``collision`` and
    ``score_increment = -mean(logdet_cov)`` (the paper's per-step score); ``reset`` returns the same keys.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        setting: str | None = None,
        map: str | None = None,
        num_targets: int | None = None,
        render_mode: str | None = None,
        overrides: Sequence[str] = (),
        device: torch.device | str = "cpu",
        render_size: int = 512,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            allowed = [None, *self.metadata["render_modes"]]
            raise ValueError(f"render_mode={render_mode!r} is not one of {allowed}")
        if isinstance(overrides, str):
            raise ValueError(f"overrides must be a list of 'key=value' strings, not the string {overrides!r}")
        self.setting, self.overrides = resolve_setting(setting, map, num_targets, overrides)
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self.torch_env = make_env(self.setting, batch_size=1, device=device, overrides=self.overrides)
        self.base_env = self.torch_env.base_env
        self.config = self.base_env.config
        self.num_targets = self.config.num_targets
        self.num_actions = int(self.base_env.primitives.shape[0])
        self.action_space = spaces.Discrete(self.num_actions)
        self.observation_space = _observation_space(self.torch_env.observation_spec)
        self._state: TensorDictBase | None = None

    # ------------------------------------------------------------------ API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; with ``seed`` the whole rollout (given the actions) is reproducible."""
        super().reset(seed=seed)
        if seed is not None:
            self.torch_env.set_seed(int(seed))
        self._state = self.torch_env.reset()
        return self._observation(), self._info()

    def step(self, action: int | np.integer) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply motion primitive ``action``; returns ``(obs, reward, terminated, truncated, info)``."""
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        index = self._check_action(action)
        request = TensorDict(
            action=torch.tensor([index], dtype=torch.int64, device=self.base_env.device),
            batch_size=[1], device=self.base_env.device,
        )
        self._state = self.torch_env.step(request)["next"]
        reward = float(self._state["reward"].reshape(-1)[0])
        terminated = bool(self._state["terminated"].reshape(-1)[0])
        truncated = bool(self._state["truncated"].reshape(-1)[0])
        return self._observation(), reward, terminated, truncated, self._info()

    def render(self) -> np.ndarray | None:
        """``uint8 [render_size, render_size, 3]`` for ``render_mode="rgb_array"`` (None without a mode)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before render()")
        state = self._state
        return render_frame(
            self.base_env.world_map(0),
            state["robot_pose"][0],
            state["target_state"][0],
            state["belief_mean"][0],
            state["belief_cov"][0],
            sensor_range=self.config.sensor.range,
            fov_deg=self.config.sensor.fov_deg,
            size=self.render_size,
            observed=state["observed"][0],
            target_heading=None if self.base_env.targets.heading is None
            else state["target_state"][0, :, self.base_env.targets.heading],
            particles=state["belief_particles"][0] if "belief_particles" in state.keys() else None,  # noqa: SIM118
        )

    # -------------------------------------------------------------- helpers
    def _check_action(self, action: Any) -> int:
        """The action as a Python int in ``[0, num_actions)``, else a ValueError naming it."""
        allowed = f"allowed indices are 0..{self.num_actions - 1} (Discrete({self.num_actions}))"
        try:
            if isinstance(action, (bool, np.bool_)):
                raise TypeError
            index = operator.index(action)
        except TypeError:
            raise ValueError(f"action {action!r} is not an integer index: {allowed}") from None
        if not 0 <= index < self.num_actions:
            raise ValueError(f"action {index} is out of range: {allowed}")
        return index

    def _observation(self) -> np.ndarray | dict[str, np.ndarray]:
        def value(key: str) -> np.ndarray:
            return self._state[key][0].detach().cpu().numpy().astype(np.float32)

        if isinstance(self.observation_space, spaces.Dict):
            return {key: value(key) for key in self.observation_space.spaces}
        return value(OBSERVATION_KEY)

    def _info(self) -> dict[str, Any]:
        state = self._state
        logdet = state["logdet_cov"][0].detach().cpu().numpy()
        return {
            "logdet_cov": logdet,
            "observed": state["observed"][0].detach().cpu().numpy().astype(bool),
            "collision": bool(state["collision"].reshape(-1)[0]),
            "score_increment": float(-logdet.mean()),
        }


def _observation_space(observation_spec) -> spaces.Box | spaces.Dict:
    """The features' ``Box`` (one world's bounds, float32), or with a map image a ``Dict`` of it and the image's
    ``Box``."""
    def box(key: str) -> spaces.Box:
        spec = observation_spec[key]
        low, high = (bound[0].cpu().numpy().astype(np.float32) for bound in (spec.space.low, spec.space.high))
        return spaces.Box(low=low, high=high, dtype=np.float32)

    if MAP_KEY in observation_spec.keys():  # noqa: SIM118 (a Composite has no `in`)
        return spaces.Dict({OBSERVATION_KEY: box(OBSERVATION_KEY), MAP_KEY: box(MAP_KEY)})
    return box(OBSERVATION_KEY)
