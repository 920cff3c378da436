"""Training: one loop for one learner or a population of independent learners.

``population`` (the objects a population builds once, shared by the loop, the checkpoints and the evaluator),
``loop`` (the loop and the members' bookkeeping), ``members`` (what members may differ in), ``components``
(networks, loss, logger), ``optimizer`` (per-member clipping and Adam), ``replay`` (per-member replay in one
storage), ``target_cache`` (ADFQ's targets), ``checkpoint`` (one checkpoint per member), ``sweeps`` (the
population launcher's one entry: grouping, ordering, resuming and stopping a sweep's populations).

Every name loads on first use, so that the apps and the launcher import the torch-free modules
(``checkpoint_names``) without loading torch and the loop.
"""

from typing import TYPE_CHECKING

from aia.runtime.lazy import lazy_names

if TYPE_CHECKING:
    from aia.training.checkpoint import TrainingState
    from aia.training.components import make_actor
    from aia.training.loop import train, train_population
    from aia.training.members import PopulationError

__getattr__ = lazy_names(__name__, {
    "TrainingState": "aia.training.checkpoint", "make_actor": "aia.training.components",
    "train": "aia.training.loop", "train_population": "aia.training.loop",
    "PopulationError": "aia.training.members"})

__all__ = ["PopulationError", "TrainingState", "make_actor", "train", "train_population"]
