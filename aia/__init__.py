"""aia: active information acquisition with batched TorchRL target tracking and deep Q-learning.

Importing ``aia`` registers the gymnasium id ``aia/TargetTracking-v0`` (without importing torch: the env
module is loaded by ``gymnasium.make``), so ``gymnasium.make("aia:aia/TargetTracking-v0")`` works in a
fresh process.
"""

import gymnasium as _gymnasium

__version__ = "0.1.0"

if "aia/TargetTracking-v0" not in _gymnasium.registry:
    _gymnasium.register(id="aia/TargetTracking-v0", entry_point="aia.envs.gym:TargetTrackingGymEnv")
