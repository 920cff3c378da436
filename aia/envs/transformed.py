"""``TrackingTransformedEnv``: the tracking env with its feature and reward transforms, stepped without a
device sync.

TorchRL's ``EnvBase.maybe_reset`` (what a collector's and a non-stopping rollout's ``step_and_maybe_reset``
call after every step) asks ``any_done``, which reads ``done.any()`` back to the host: on CUDA a
synchronisation every step. The tracking env knows on the host when no world can be done
(:meth:`TargetTrackingEnv.all_running`: its episodes end at the time limit only), so this env answers
``False`` then without reading the device, and asks TorchRL otherwise (once an episode).
"""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.envs import ExcludeTransform, SelectTransform, TransformedEnv

from aia.transforms import BeliefFeatures, InfoReward, LocalMap

# transforms that write no done entry (the key filters at most drop one): with only these, no world is done
# while the base env says so (the training loop appends a SelectTransform)
_DONE_PRESERVING = (BeliefFeatures, InfoReward, LocalMap, SelectTransform, ExcludeTransform)
_ALL_RUNNING = "aia_all_running"  # the env's cache entry: the base env's all_running, or False


class TrackingTransformedEnv(TransformedEnv):
    """A ``TransformedEnv`` over :class:`~aia.envs.tracking.TargetTrackingEnv` whose ``any_done`` costs no
    device sync while every world is inside its episode. A transform appended later that is not one of the
    feature and reward transforms or a key filter (a ``StepCounter`` may end episodes) turns the shortcut off."""

    def any_done(self, tensordict: TensorDictBase) -> bool:
        """As ``EnvBase.any_done`` (and writes ``"_reset"`` the same way when a world is done)."""
        # kept in TorchRL's cache of the env, which it empties whenever a transform is added or removed: looked
        # up every step, the transforms and the base env cost 4 us, TorchRL's own check on the CPU 2 us
        all_running = self._cache.get(_ALL_RUNNING)
        if all_running is None:
            preserving = all(isinstance(t, _DONE_PRESERVING) for t in self.transform)
            all_running = self._cache[_ALL_RUNNING] = self.base_env.all_running if preserving else False
        if all_running and all_running():
            return False
        return super().any_done(tensordict)
