"""TrackingTransformedEnv: the host-side "no world is done" shortcut gives TorchRL's answers and rollouts."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs import StepCounter, TransformedEnv

from aia.envs import TrackingTransformedEnv, make_env, make_transforms


def test_all_running_is_the_device_truth_through_partial_resets():
    env = make_env("empty1", batch_size=3, seed=0, overrides=["max_steps=4"], transforms=False)
    env.reset()
    actions = TensorDict(action=torch.zeros(3, dtype=torch.int64), batch_size=[3])
    for step in range(12):
        if step == 2:  # world 1 starts a new episode: the others run on, two steps ahead of it
            env.reset(TensorDict(_reset=torch.tensor([[False], [True], [False]]), batch_size=[3]))
        done = env.step(actions.clone())["next", "done"]
        assert env.all_running() == (not done.any()), step
        assert env._steps_bound == int(env._step_count.max())
        if done.any():
            env.reset(TensorDict(_reset=done.clone(), batch_size=[3]))


def test_a_rollout_is_that_of_torchrls_own_transformed_env():
    ours = make_env("empty1", batch_size=2, seed=3, overrides=["max_steps=5"])
    theirs = make_env("empty1", batch_size=2, seed=3, overrides=["max_steps=5"], transforms=False)
    theirs = TransformedEnv(theirs, make_transforms(theirs.config))
    assert isinstance(ours, TrackingTransformedEnv)
    torch.manual_seed(0)
    a = ours.rollout(13, break_when_any_done=False)
    torch.manual_seed(0)
    b = theirs.rollout(13, break_when_any_done=False)
    assert (a == b).all()
    assert int(a["next", "done"].sum()) == 2 * 2  # two episodes ended in each world


def test_a_transform_that_may_end_episodes_turns_the_shortcut_off():
    env = make_env("empty1", batch_size=1, seed=0)  # episodes of 100 steps
    env.rollout(2, break_when_any_done=False)  # the shortcut is set up (and cached) ...
    env.append_transform(StepCounter(max_steps=3))  # ... and dropped with TorchRL's cache
    data = env.rollout(7, break_when_any_done=False)
    assert data["next", "truncated"][0, :, 0].tolist() == [False, False, True, False, False, True, False]
    assert data["next", "step_count"][0, :, 0].tolist() == [1, 2, 3, 1, 2, 3, 1]
