"""TorchRL transforms that turn the raw tracking state into the RL observation and reward."""

from aia.transforms.belief_features import BeliefFeatures, belief_features
from aia.transforms.info_reward import InfoReward, info_reward

__all__ = ["BeliefFeatures", "InfoReward", "belief_features", "info_reward"]
