"""Training: one loop for one learner or a population of independent learners (:mod:`aia.training.loop`).

``loop`` (the loop and its bookkeeping), ``members`` (what members may differ in), ``components`` (networks,
loss, logger), ``optimizer`` (per-member clipping and Adam), ``replay`` (per-member replay in one storage),
``checkpoint`` (one checkpoint per member).
"""

from aia.training.components import make_actor
from aia.training.loop import TrainingState, train, train_population
from aia.training.members import MEMBER_KEYS, PopulationError, check_population, population_signature

__all__ = [
    "MEMBER_KEYS",
    "PopulationError",
    "TrainingState",
    "check_population",
    "make_actor",
    "population_signature",
    "train",
    "train_population",
]
