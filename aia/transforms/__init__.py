"""TorchRL transforms that turn the raw tracking state into the RL observation and reward."""

from aia.transforms.belief_features import BeliefFeatures, belief_features
from aia.transforms.info_reward import InfoReward, info_reward
from aia.transforms.local_map import LOCAL_MAP_KEY, LocalMap

__all__ = ["LOCAL_MAP_KEY", "BeliefFeatures", "InfoReward", "LocalMap", "belief_features", "info_reward"]
