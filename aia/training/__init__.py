"""Training: one loop for one learner or a population of independent learners.

``population`` (the objects a population builds once, shared by the loop, the checkpoints and the evaluator),
``loop`` (the loop and the members' bookkeeping), ``members`` (what members may differ in), ``components``
(networks, loss, logger), ``optimizer`` (per-member clipping and Adam), ``replay`` (per-member replay in one
storage), ``target_cache`` (ADFQ's targets), ``checkpoint`` (one checkpoint per member), ``sweeps`` (the
population launcher's one entry: grouping, ordering, resuming and stopping a sweep's populations).
"""

from aia.training.checkpoint import TrainingState
from aia.training.components import make_actor
from aia.training.loop import train, train_population
from aia.training.members import PopulationError

__all__ = ["PopulationError", "TrainingState", "make_actor", "train", "train_population"]
