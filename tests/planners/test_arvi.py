"""ARVI: exhaustive-search equality, the env's covariance steps, pruning, collisions, the policy and its scores."""

from __future__ import annotations

import math
import re

import pytest
import torch
from torchrl.envs import StepCounter

from aia.config.errors import ConfigError
from aia.envs import belief, make_env
from aia.envs.dynamics import se2_step
from aia.envs.sensing import MapGeometry
from aia.evaluation import episode_scores, run_episodes
from aia.planners import ARVIConfig, ARVIPlanner, ARVIPolicy, model, pruning, search, to_arvi_config
from aia.planners.tree import Expansion
from aia.policies import RandomPolicy


def _config(**overrides) -> ARVIConfig:
    """A deterministic budget (no wall clock), so that results do not depend on the machine."""
    return ARVIConfig(**{"time_budget": None, "max_passes": 0, **overrides})


def _scene(num_worlds: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A robot at the centre of the empty map and one target ahead of it, moving, in every world."""
    pose = torch.tensor([50.0, 50.0, 0.0]).repeat(num_worlds, 1)
    mean = torch.tensor([[54.0, 51.0, 0.3, 0.2]]).repeat(num_worlds, 1, 1)
    cov = torch.diag(torch.tensor([3.0, 2.0, 1.0, 0.5])).repeat(num_worlds, 1, 1, 1)
    return pose, mean, cov


def _exhaustive(env, pose, mean, cov, horizon):
    """Cost of every one of the 12^T action sequences, simulated step by step (no pruning, no tree)."""
    f64 = torch.float64
    primitives = env.primitives.to(f64)
    num_actions = primitives.shape[0]
    sequences = torch.cartesian_prod(*[torch.arange(num_actions)] * horizon).reshape(-1, horizon)
    count = sequences.shape[0]
    pose = pose.to(f64).expand(count, 3)
    mean, cov = mean.to(f64)[0], cov.to(f64).expand(count, *cov.shape[1:])
    transition, noise = env.belief_filter.transition.to(f64), env.belief_filter.model.noise.to(f64)
    meas_noise = env.meas_noise.to(f64)
    half_fov = math.radians(env.config.sensor.fov_deg) / 2
    total = torch.zeros(count, dtype=f64)
    for t in range(horizon):
        pose = se2_step(pose, primitives[sequences[:, t]], env.config.dt)
        mean = mean @ transition.T
        cov = belief.predict_cov(cov, transition, noise)
        polar = belief.range_bearing(mean[:, :2].expand(count, -1, -1), pose[:, None, :])
        visible = (polar[..., 0] <= env.config.sensor.range) & (polar[..., 1].abs() <= half_fov)
        jacobian = belief.measurement_jacobian(mean[:, :2].expand(count, -1, -1), pose[:, None, :])
        cov = torch.where(visible[..., None, None], belief.update_cov(cov, jacobian, meas_noise)[0], cov)
        total += belief.logdet(cov).sum(-1)
    return sequences, total


# ------------------------------------------------------------------------------------------ search
@pytest.mark.parametrize("horizon", [1, 2, 3])
def test_without_pruning_the_plan_is_the_exhaustive_optimum(horizon):
    env = make_env("empty1", transforms=False, overrides=["belief.det_cap=null"])
    pose, mean, cov = _scene()
    # delta0 < 1 prunes nothing: one pass after the greedy chain builds the full tree.
    result = ARVIPlanner(env, _config(horizon=horizon, replan_every=1, delta0=0.9, max_passes=1)).plan(pose, mean, cov)
    sequences, costs = _exhaustive(env, pose, mean, cov, horizon)
    assert result.nodes.item() == sum(12**t for t in range(1, horizon + 1))
    assert result.cost.item() == pytest.approx(costs.min().item(), rel=1e-12, abs=1e-9)
    chosen = (sequences == result.actions).all(-1)
    assert costs[chosen].item() == pytest.approx(costs.min().item(), rel=1e-12, abs=1e-9)
    # the optimum is not what the greedy chain alone finds when looking ahead matters
    assert costs.min() < costs.max() - 1.0


def test_batched_worlds_plan_as_if_alone():
    env = make_env("empty1", transforms=False)
    pose, mean, cov = _scene(3)
    pose[1] = torch.tensor([20.0, 70.0, 2.0])
    mean[2, 0, :2] = torch.tensor([45.0, 47.0])
    planner = ARVIPlanner(env, _config(max_passes=26))
    together = planner.plan(pose, mean, cov)
    for w in range(3):
        alone = planner.plan(pose[w : w + 1], mean[w : w + 1], cov[w : w + 1])
        assert torch.equal(alone.actions[0], together.actions[w])
        assert alone.cost.item() == together.cost[w].item() and alone.nodes.item() == together.nodes[w].item()
    assert together.passes == 26 and together.delta == pytest.approx(3.0 - 25 * 0.05)
    assert (together.nodes > 12 * 12).all()  # the tree grew past the greedy chain


def test_skipped_passes_change_nothing():
    """Fast-forwarding over passes that cannot change the tree gives the pass-by-pass result."""
    env = make_env("empty1", transforms=False)
    pose, mean, cov = _scene()
    planner = ARVIPlanner(env, _config(max_passes=27))
    schedule = search._Search(planner, pose.double(), mean.double(), cov.double(), torch.arange(1))
    schedule._next_pass = lambda k, group: k + 1  # the plain schedule: every pass runs
    plain = schedule.run()[0]
    fast = planner.plan(pose, mean, cov)
    assert torch.equal(plain.actions, fast.actions) and torch.equal(plain.nodes, fast.nodes)
    assert plain.cost.item() == fast.cost.item() and plain.delta == fast.delta


def test_a_time_budget_reads_the_clock_within_a_big_level(monkeypatch):
    """Under a time budget a level's expansion comes in chunks with the clock read between them, so a deep
    pass's level of a million children cannot overrun the budget; when the clock runs out mid-level the
    plan is read from the tree as it stands."""
    env = make_env("empty1", transforms=False)
    pose, mean, cov = _scene()
    expanded = []
    extend = search.Expansion.extend

    def counting(self, below, level, parents, positions, maps):
        expanded.append(parents.numel())
        return extend(self, below, level, parents, positions, maps)

    monkeypatch.setattr(search.Expansion, "extend", counting)
    monkeypatch.setattr(search, "_TIMED_CHUNK", 64)
    untimed = ARVIPlanner(env, _config(max_passes=36)).plan(pose, mean, cov)
    assert max(expanded) > 64  # a pass budget expands a level's fresh nodes at once
    expanded.clear()
    clock_reads = []

    def out_of_time(self):  # the clock runs out at its 40th reading
        clock_reads.append(len(expanded))
        return len(clock_reads) > 40

    monkeypatch.setattr(search._Search, "_out_of_time", out_of_time)
    timed = ARVIPlanner(env, ARVIConfig(time_budget=1.0, max_passes=36)).plan(pose, mean, cov)
    assert max(expanded) <= 64 and len(clock_reads) == 41
    assert timed.nodes.item() < untimed.nodes.item() and timed.actions.shape == (1, 12)
    assert not env.geometry.in_collision(_rollout_positions(env, pose, timed.actions[0])).any()


def _rollout_positions(env, pose, actions):
    """The robot's positions along a plan (one step per action)."""
    positions, current = [], pose.double()
    for action in actions.tolist():
        current = se2_step(current, env.primitives.double()[action], env.config.dt)
        positions.append(current[..., :2])
    return torch.cat(positions)


# ------------------------------------------------------------------------------------ filter model
def test_covariance_steps_equal_the_env_filter():
    """Same poses, same visibility: the planner's covariance step is the env's EKF covariance (det cap on)."""
    env = make_env("obstacles1", batch_size=64, seed=2, transforms=False, overrides=["dtype=float64"])
    tracking = model.TrackingModel.from_env(env)
    td = env.reset()
    random = RandomPolicy(12, seed=2)
    seen = torch.zeros(0, dtype=torch.bool)
    for _ in range(25):
        cov, mean = td["belief_cov"], td["belief_mean"]
        td = env.step(random(td))["next"]
        predicted_xy = (mean @ env.belief_filter.transition.T)[..., :2]
        predicted, logdet = model.predict_cov(tracking, cov, belief.logdet(cov))
        step, step_logdet = model.update_visible(tracking, predicted, logdet, td["robot_pose"], predicted_xy,
                                                 td["observed"])
        torch.testing.assert_close(step, td["belief_cov"], rtol=1e-12, atol=1e-12)
        assert torch.equal(step_logdet, belief.logdet(step))  # the log dets the tree keeps are the covariances'
        visible = model.visible_targets(tracking.geometry, td["robot_pose"], td["target_state"][..., :2])
        assert torch.equal(visible, td["observed"])
        seen = torch.cat((seen, td["observed"].flatten()))
    assert 0.05 < seen.float().mean() < 0.95  # both branches were exercised


def test_det_cap_keeps_an_unseen_covariance():
    env = make_env("empty1", transforms=False)  # det cap 1e6 (on by default)
    tracking = model.TrackingModel.from_env(env)
    cov = 30.0 * torch.eye(4, dtype=torch.float64)  # det 810000
    for _ in range(100):
        cov = model.predict_cov(tracking, cov, belief.logdet(cov))[0]
    assert 0 < math.log(1e6) - belief.logdet(cov).item() < 0.2  # grew up to the cap, then stopped
    kept, kept_logdet = model.predict_cov(tracking, cov, belief.logdet(cov))
    torch.testing.assert_close(kept, cov, rtol=0, atol=0)
    assert torch.equal(kept_logdet, belief.logdet(cov))
    narrow = torch.eye(4, dtype=torch.float64)
    assert not torch.equal(model.predict_cov(tracking, narrow, belief.logdet(narrow))[0], narrow)


# ------------------------------------------------------------------------------------------ pruning
def _prune(cost, xy, delta, eps=math.inf, diag=None, group=None):
    cost = torch.tensor(cost, dtype=torch.float64)
    group = torch.zeros(len(cost), dtype=torch.long) if group is None else torch.tensor(group)
    diag = None if diag is None else torch.tensor(diag, dtype=torch.float64)
    return pruning.prune(cost, torch.tensor(xy, dtype=torch.float64), diag, group, delta, eps)


def test_a_node_within_delta_of_a_better_one_is_dropped():
    # distances sqrt(d^2 + 1): 0-1 is sqrt(2), 0-2 is sqrt(10), 1-2 is sqrt(5)
    result = _prune([1.0, 2.0, 3.0], [[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]], delta=2.0)
    assert result.keep.tolist() == [True, False, True]
    assert result.critical == pytest.approx(math.sqrt(2))
    assert _prune([1.0, 2.0, 3.0], [[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]], delta=1.4).keep.all()  # < sqrt(2)
    assert _prune([1.0, 2.0, 3.0], [[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]], delta=0.99).critical == -math.inf


def test_suppression_follows_ascending_cost_not_input_order():
    # A chain 0 - 1 - 2 (each within delta of the next, 0 and 2 apart): 1 is dropped by 0, so 2 survives.
    xy = [[2.4, 0.0], [0.0, 0.0], [1.2, 0.0]]
    assert _prune([3.0, 1.0, 2.0], xy, delta=1.8).keep.tolist() == [True, True, False]
    # the best of each group is kept, and groups never suppress each other
    result = _prune([5.0, 1.0, 2.0, 4.0], [[0, 0], [0, 0], [0.1, 0], [0.2, 0]], delta=3.0, group=[0, 0, 1, 1])
    assert result.keep.tolist() == [False, True, True, False]


def test_eps_redundancy_on_hand_built_covariances():
    xy = [[0.0, 0.0], [0.5, 0.0]]  # within delta = 2
    better, worse = [1.0, 1.0, 1.0, 1.0], [2.0, 2.0, 2.0, 2.0]
    # the candidate's diagonal dominates the kept node's: redundant for any eps >= 0, dropped
    assert _prune([1.0, 2.0], xy, 2.0, eps=0.0, diag=[better, worse]).keep.tolist() == [True, False]
    # a candidate sharper in one entry by 0.5 is redundant only for eps >= 0.5
    sharper = [2.0, 0.5, 2.0, 2.0]
    assert _prune([1.0, 2.0], xy, 2.0, eps=0.4, diag=[better, sharper]).keep.tolist() == [True, True]
    assert _prune([1.0, 2.0], xy, 2.0, eps=0.5, diag=[better, sharper]).keep.tolist() == [True, False]
    assert _prune([1.0, 2.0], xy, 2.0, diag=[better, sharper]).keep.tolist() == [True, False]  # eps = inf


def _sequential_suppression(cost, xy, group, delta):
    """The textbook loop: visit in ascending cost, keep unless a kept node of the group is within delta."""
    kept = []
    for i in sorted(range(len(cost)), key=lambda i: (cost[i], i)):
        close = [j for j in kept if group[j] == group[i] and (xy[i] - xy[j]).square().sum() + 1 <= delta**2]
        if not close:
            kept.append(i)
    return sorted(kept)


@pytest.mark.parametrize("implementation", [pruning.prune, pruning.prune_tensors])  # the CPU kernel, tensor ops
@pytest.mark.parametrize("count", [200, 800])  # the tensor ops' dense and grid neighbour search
def test_pruning_equals_sequential_suppression(count, implementation):
    generator = torch.Generator().manual_seed(count)
    xy = 10 * torch.rand(count, 2, generator=generator, dtype=torch.float64)
    cost = torch.rand(count, generator=generator, dtype=torch.float64)
    group = torch.randint(0, 3, (count,), generator=generator)
    result = implementation(cost, xy, None, group, delta=1.6)
    assert result.keep.nonzero().squeeze(-1).tolist() == _sequential_suppression(cost, xy, group, 1.6)


@pytest.mark.parametrize("delta", [0.9, 1.3, 2.5, math.inf])  # nothing prunable, close pairs, one cell per world
@pytest.mark.parametrize("eps", [math.inf, 0.0, 0.05])
def test_the_cpu_kernel_equals_the_tensor_ops(delta, eps):
    generator = torch.Generator().manual_seed(7)
    count, worlds = 3000, 4
    xy = 20 * torch.rand(count, 2, generator=generator, dtype=torch.float64)
    cost = torch.randint(0, 400, (count,), generator=generator).double()  # many ties: broken by index
    diag = torch.rand(count, 8, generator=generator, dtype=torch.float64)
    group = torch.randint(0, worlds, (count,), generator=generator)
    labels = group % 2  # two budget groups of two worlds
    args = (cost, xy, diag, group, delta, eps, 1.0, ((0.0, 0.0), (20.0, 20.0)), labels, 2)
    kernel, tensors = pruning.prune(*args), pruning.prune_tensors(*args)
    assert torch.equal(kernel.keep, tensors.keep)
    assert kernel.criticals == tensors.criticals  # the same arithmetic: equal, not close
    assert 0 < int(kernel.keep.sum()) < count or delta < 1


# ---------------------------------------------------------------------------------------- collisions
def test_plans_never_collide():
    env = make_env("obstacles1", batch_size=16, seed=5, transforms=False)
    td = env.reset()
    # Half of the robots start right in front of the west wall, facing it.
    td["robot_pose"][:8] = torch.tensor([1.2, 18.0, math.pi])
    env.state["robot_pose"] = td["robot_pose"].clone()
    result = ARVIPlanner(env, _config(max_passes=26)).plan(td["robot_pose"], td["belief_mean"], td["belief_cov"])
    assert not env.geometry.in_collision(
        se2_step(td["robot_pose"][:8], env.primitives[result.actions[:8, 0]], env.config.dt)[:, :2]).any()
    for t in range(result.actions.shape[1]):
        td = env.step(td.set("action", result.actions[:, t]))["next"]
        assert not td["collision"].any(), f"a planned primitive collided at step {t}"


def test_a_robot_inside_an_obstacle_is_named():
    env = make_env("obstacles1", transforms=False)
    pose, mean, cov = _scene()
    pose[0, :2] = torch.tensor([5.0, 10.0])  # inside the box x 2.6-9.4, y 7.4-17.0
    with pytest.raises(ValueError, match=r"worlds \[0\]: no collision-free path of 12 steps"):
        ARVIPlanner(env, _config()).plan(pose, mean, cov)


# -------------------------------------------------------------------------------------------- policy
def test_policy_replans_every_k_steps_and_after_resets():
    env = make_env("empty1", batch_size=2, seed=0, overrides=["max_steps=7"])
    env.append_transform(StepCounter())
    policy = ARVIPolicy(env, _config(horizon=6, replan_every=5))
    calls = []
    plan = policy.planner.plan

    def spy(pose, mean, cov, worlds):
        calls.append(pose.shape[0])
        policy_result = plan(pose, mean, cov, worlds)
        spy.actions.append(policy_result.actions)
        return policy_result

    spy.actions = []
    policy.planner.plan = spy
    rollout = env.rollout(12, policy=lambda td: policy(td.exclude("target_state")), break_when_any_done=False)
    # steps 0 and 5 of the first episode, step 0 of the second (after the reset at 7)
    assert calls == [2, 2, 2]
    assert torch.equal(rollout["action"][:, :5], spy.actions[0][:, :5])
    assert torch.equal(rollout["action"][:, 5:7], spy.actions[1][:, :2])
    assert torch.equal(rollout["action"][:, 7:12], spy.actions[2][:, :5])


def test_policy_asks_for_a_step_counter():
    env = make_env("empty1", seed=0)
    with pytest.raises(KeyError, match="StepCounter"):
        ARVIPolicy(env, _config())(env.reset())


def test_arvi_beats_random_and_one_step_greedy_on_a_seeded_episode():
    env = make_env("empty1", batch_size=1, seed=9)
    env.append_transform(StepCounter())

    def score(policy) -> float:
        return episode_scores(run_episodes(env, policy, seed=9)).item()

    planner = score(ARVIPolicy(env, _config(max_passes=26)))
    greedy = score(ARVIPolicy(env, _config(horizon=1, replan_every=1)))  # one-step information greedy
    random = score(RandomPolicy(12, seed=9))
    assert planner > greedy + 1000 and planner > random + 1000


def test_min_range_hides_close_predicted_targets():
    env = make_env("empty1", transforms=False)
    tracking = model.TrackingModel.from_env(env)
    pose = torch.tensor([[50.0, 50.0, 0.0]])
    ahead = torch.tensor([[[51.0, 50.0], [55.0, 50.0], [45.0, 50.0]]])  # 1 m and 5 m ahead, 5 m behind
    assert model.visible_targets(tracking.geometry, pose, ahead).tolist() == [[True, True, False]]
    assert model.visible_targets(tracking.geometry, pose, ahead, min_range=2.0).tolist() == [[False, True, False]]


def test_min_range_keeps_the_robot_off_the_belief_mean():
    """Seed 4: planning with the sensing rule as written, the robot drives onto the belief mean and tracks
    poorly; counting on measurements only from 2 m on, it keeps the target in view."""
    env = make_env("empty1", batch_size=1, seed=4)
    env.append_transform(StepCounter())

    def score(min_range: float) -> float:
        policy = ARVIPolicy(env, _config(max_passes=10, min_range=min_range))
        return episode_scores(run_episodes(env, policy, seed=4)).item()

    assert score(2.0) > score(0.0) + 1000


# -------------------------------------------------------------------------------------------- config
def test_bad_parameters_are_named():
    cases = [({"horizon": 0}, "planner.horizon=0: expected an integer >= 1"),
             ({"replan_every": 13}, "planner.replan_every=13: expected at most planner.horizon=12"),
             ({"time_budget": None}, "planner.time_budget=null: expected a number >= 0 while max_passes and max_nodes"),
             ({"eps": -1.0}, "planner.eps=-1.0: expected a number >= 0"),
             ({"min_range": -0.5}, "planner.min_range=-0.5: expected a number >= 0"),
             ({"max_nodes": -3}, "planner.max_nodes=-3: expected an integer >= 0 or null"),
             ({"horizon": True}, "planner.horizon=True: expected an integer >= 1")]
    for fields, words in cases:
        with pytest.raises(ConfigError, match=re.escape(words)):
            ARVIConfig(**fields)
    unknown = "planner.horizn=3: expected one of planner's keys (did you mean planner.horizon?): horizon, "
    with pytest.raises(ConfigError, match=re.escape(unknown)):
        to_arvi_config({"horizn": 3})
    with pytest.raises(ConfigError, match=re.escape("planner.delta0='wide': expected a number > 0")):
        to_arvi_config({"delta0": "wide"})
    assert to_arvi_config({"horizon": 6, "eps": "inf"}) == ARVIConfig(horizon=6)


def test_arvi_refuses_a_setting_without_a_kalman_filter_in_one_line():
    with pytest.raises(ConfigError, match=r"env.belief.filter='ukf': expected kf \(ARVI plans"):
        model.TrackingModel.from_env(make_env("ttenv_v2", transforms=False))


def test_on_per_world_maps_each_world_plans_as_on_its_own_map():
    """Random maps: a world's plan (its own budget group) equals the plan on a fixed map that is its map, in any
    order and subset of the env's worlds."""
    env = make_env("random_obstacles", batch_size=3, seed=2, transforms=False)
    td = env.reset()
    config = _config(max_nodes=400, max_passes=None)
    state = (td["robot_pose"], td["belief_mean"], td["belief_cov"])
    worlds = torch.tensor([2, 0, 1])
    together = ARVIPlanner(env, config).plan_groups(*(x[worlds] for x in state), torch.arange(3), worlds)
    geometry, sensor = env.geometry, env.config.sensor
    for group, world in enumerate(worlds.tolist()):
        alone = ARVIPlanner(env, config)
        fixed = MapGeometry(env.world_map(world), geometry.margin, geometry.sensor_range, geometry.fov,
                            sensor.obstacle_ray_spacing, geometry.supersample)
        alone.model = alone.model._replace(geometry=fixed)
        alone.expansion = Expansion(alone.model, config.arc_checks, config.min_range)
        expected = alone.plan(*(x[world : world + 1] for x in state))
        assert torch.equal(together[group].actions, expected.actions)
        assert torch.equal(together[group].nodes, expected.nodes) and together[group].cost == expected.cost
    assert (torch.stack([plan.nodes for plan in together]) > 100).all()
