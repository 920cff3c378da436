"""Every purpose and stream number of the counter-based draws, in one place.

A draw is a function of ``(key, counter, stream, slot)`` (:func:`aia.rng.random_bits`), so two users of one key
that pass the same stream draw the same bits. Keys come in families: a world's episode key
(:func:`aia.rng.world_keys`, the env's), and one family per :class:`Purpose` of a seed's keys
(:func:`aia.rng.seed_keys`). Within a family each stream number must be unique; ``@unique`` refuses a
duplicate at import. The values are part of every run's numbers: changing one changes what a seed draws.
"""

from __future__ import annotations

from enum import IntEnum, unique


@unique
class Purpose(IntEnum):
    """What a seed's keys are for (:func:`aia.rng.seed_keys`): keeps each user's keys apart from the others'."""

    ACTING = 1      # PopulationQPolicy: a member's exploration (ExplorationStream)
    REPLAY = 2      # MemberReplay: a member's sample indices (ReplayStream)
    EVALUATION = 3  # SnapshotPolicy: a snapshot group's evaluation noise (ExplorationStream)


@unique
class WorldStream(IntEnum):
    """The draws made with a world's episode key (the env, its targets and its belief filter)."""

    STEP = 1       # TargetTrackingEnv's step: the targets' motion noise and the sensor noise
    RESET = 2      # TargetTrackingEnv's reset: the robot's, the targets' and the beliefs' initial states
    MAP = 3        # aia.envs.map_generator: a random map's layout (counter: the attempt)
    CONTROL = 11   # BeliefFilter.control_uniforms: the random controls a filter assumes
    PARTICLE = 12  # ParticleFilter: the initial spread and the process noise
    RESAMPLE = 13  # ParticleFilter: the systematic resampling's uniforms
    ROUGHENING = 14  # ParticleFilter: the roughening's uniforms


@unique
class ExplorationStream(IntEnum):
    """The exploration draws per step made with Purpose.ACTING's or Purpose.EVALUATION's keys."""

    EXPLORE = 0   # epsilon-greedy: whether a world explores
    RANDOM = 1    # the random action of a world that explores (and of the warm-up)
    THOMPSON = 2  # ADFQ's Thompson sampling: the normals of q_a ~ N(mean_a, sd_a^2)


@unique
class ReplayStream(IntEnum):
    """The draws made with Purpose.REPLAY's keys (counter: the batches drawn)."""

    INDICES = 0  # a batch's uniform row indices
