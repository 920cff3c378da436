"""Counter-based randomness: every draw a pure function of (key, counter, stream, slot), no generator state.

``counter.py`` holds the hash, the keys and the draws; ``streams.py`` declares every purpose and stream
number that the env, the policies and the replay pass to them.
"""

from aia.rng.counter import (
    CounterStream,
    episode_keys,
    mix32,
    normal,
    random_bits,
    seed_keys,
    slot_keys,
    uniform,
    world_keys,
)
from aia.rng.streams import ExplorationStream, Purpose, ReplayStream, WorldStream

__all__ = ["CounterStream", "ExplorationStream", "Purpose", "ReplayStream", "WorldStream", "episode_keys", "mix32",
           "normal", "random_bits", "seed_keys", "slot_keys", "uniform", "world_keys"]
