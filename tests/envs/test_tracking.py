"""TargetTrackingEnv: specs, motion, belief invariants, resets, seeding and input errors."""

from __future__ import annotations

import math

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from aia.envs import TargetTrackingEnv, TrackingConfig, load_env_config, make_env
from aia.envs.dynamics import double_integrator
from aia.envs.factory import available_settings

PAPER_SETTINGS = ("empty1", "obstacles1", "small2", "small3")


def _step(env: TargetTrackingEnv, actions) -> torch.Tensor:
    td = env.base_env.state.clone() if hasattr(env, "base_env") else env.state.clone()
    td.set("action", torch.as_tensor(actions, dtype=torch.int64))
    return env.step(td)["next"]


def test_presets_listed():
    settings = available_settings()
    for name in PAPER_SETTINGS:
        assert name in settings and f"{name}_2019" in settings


@pytest.mark.parametrize("setting", PAPER_SETTINGS)
@pytest.mark.parametrize("batch_size", [1, 64])
def test_check_env_specs(setting, batch_size):
    env = make_env(setting, batch_size=batch_size, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(5)
    n = env.base_env.num_targets
    assert td["next", "observation"].shape == (batch_size, 5, 6 * n + 2)
    assert td["next", "belief_cov"].shape == (batch_size, 5, n, 4, 4)


@pytest.mark.parametrize("setting", ["empty1_2019", "obstacles1_2019", "small3_2019"])
def test_2019_presets_pass_specs(setting):
    check_env_specs(make_env(setting, batch_size=3, seed=1), seed=1)


def test_2019_preset_choices():
    paper, old = load_env_config("obstacles1"), load_env_config("obstacles1_2019")
    assert (paper.target.q, old.target.q) == (0.01, 0.001)
    assert old.target.init_distance == [8.0, 8.0] and old.belief.init_offset_shape == "box"
    assert old.belief.clip_to_map and old.belief.speed_clip == 2.0 and old.robot.target_margin == 1.0
    assert old.features.relative_velocity == "2019" and paper.features.relative_velocity == "exact"
    assert old.map == paper.map == "obstacles4"


# ------------------------------------------------------------------ robot
def test_robot_step_matches_hand_computed_pose():
    env = TargetTrackingEnv(load_env_config("empty1"), batch_size=3, seed=0)
    env.reset()
    env.state["robot_pose"] = torch.tensor([[50.0, 50.0, 0.0], [50.0, 50.0, 0.0], [20.0, 30.0, math.pi / 2]])
    # far-away targets so that the robot is never blocked by them
    env.state["target_state"] = torch.tensor([[[90.0, 90.0, 0.0, 0.0]]]).expand(3, 1, 4).clone()
    # a=1: (v, w) = (3, 0); a=3: (2, pi/2); a=11: (0, -pi/2)
    nxt = _step(env, [1, 3, 11])
    pose = nxt["robot_pose"]
    assert torch.allclose(pose[0], torch.tensor([51.5, 50.0, 0.0]), atol=1e-5)
    # arc: x += v/w (sin(th + w dt) - sin th), y += v/w (cos th - cos(th + w dt)), w dt = pi/4
    r = 2.0 / (math.pi / 2)
    expected = torch.tensor([50.0 + r * math.sin(math.pi / 4), 50.0 + r * (1 - math.cos(math.pi / 4)), math.pi / 4])
    assert torch.allclose(pose[1], expected, atol=1e-5)
    assert torch.allclose(pose[2], torch.tensor([20.0, 30.0, math.pi / 4]), atol=1e-5)
    assert torch.equal(nxt["robot_velocity"][1], torch.tensor([2.0, math.pi / 2]))
    assert not nxt["collision"].any()


def test_robot_collision_keeps_position_and_turns():
    env = TargetTrackingEnv(load_env_config("empty1"), batch_size=2, seed=0)
    env.reset()
    # 0.9 m from the left bound facing it: a 1.5 m move ends outside the 0.5 m margin
    env.state["robot_pose"] = torch.tensor([[0.9, 50.0, math.pi - 1e-3], [0.9, 50.0, math.pi - 1e-3]])
    env.state["target_state"] = torch.tensor([[[90.0, 90.0, 0.0, 0.0]]]).expand(2, 1, 4).clone()
    nxt = _step(env, [1, 0])  # (3, 0) straight into the wall; (3, pi/2) turning into it
    pose = nxt["robot_pose"]
    assert nxt["collision"].tolist() == [True, True]
    assert torch.allclose(pose[:, :2], torch.tensor([[0.9, 50.0], [0.9, 50.0]]))
    assert pose[0, 2].item() == pytest.approx(math.pi - 1e-3, abs=1e-5)
    assert pose[1, 2].item() == pytest.approx(-math.pi + math.pi / 4 - 1e-3, abs=1e-5)


def test_2019_target_margin_blocks_robot():
    config = load_env_config("empty1", ["robot.target_margin=1.0"])
    env = TargetTrackingEnv(config, batch_size=2, seed=0)
    env.reset()
    env.state["robot_pose"] = torch.tensor([[50.0, 50.0, 0.0], [50.0, 50.0, 0.0]])
    env.state["target_state"] = torch.tensor([[[51.8, 50.0, 0.0, 0.0]], [[52.2, 50.0, 0.0, 0.0]]])
    nxt = _step(env, [4, 4])  # (2, 0): 1 m forward, to 0.8 m (blocked) and 1.2 m (free) from the target
    assert nxt["robot_pose"][0, 0].item() == pytest.approx(50.0)
    assert nxt["robot_pose"][1, 0].item() == pytest.approx(51.0)
    assert not nxt["collision"].any()  # the margin rule is not a collision


# ---------------------------------------------------------------- targets
def test_target_transition_statistics_match_a_and_w():
    config = load_env_config("empty1", ["target.q=0.5"])
    B = 40000
    env = TargetTrackingEnv(config, batch_size=B, seed=3)
    env.reset()
    start = torch.tensor([50.0, 50.0, 0.3, -0.2])
    env.state["target_state"] = start.expand(B, 1, 4).clone()
    nxt = _step(env, torch.full((B,), 10))
    transition, noise = double_integrator(0.5, 0.5)
    residual = nxt["target_state"][:, 0].double() - (transition @ start.double())
    assert residual.mean(0).abs().max().item() < 4 * noise.diagonal().sqrt().max().item() / math.sqrt(B)
    cov = torch.cov(residual.T)
    assert torch.allclose(cov, noise, atol=4 * noise.diagonal().max().item() * math.sqrt(2 / B))


def test_targets_stay_in_free_space_for_40000_world_steps():
    """160 worlds x 250 steps (as many bounces off obstacles and walls as 16 worlds x 2,500 steps: about 6,500
    velocity reversals, in a quarter of the CPU time)."""
    config = load_env_config("obstacles1", ["max_steps=250"])
    env = TargetTrackingEnv(config, batch_size=160, seed=5)
    td = env.rollout(250, break_when_any_done=False)
    positions = td["next", "target_state"][..., :2]
    assert not env.geometry.in_collision(positions).any()
    cells = torch.floor(positions / env.map.resolution).long()
    assert not env.map.occupancy[cells[..., 1], cells[..., 0]].any()
    # they do move around the map, and some of them bounced
    assert (positions.flatten(0, 2).std(0) > 2.0).all()


# ----------------------------------------------------------------- belief
def test_covariance_stays_symmetric_positive_definite():
    env = make_env("small3", batch_size=16, seed=2)
    td = env.rollout(600, break_when_any_done=False)
    cov = td["next", "belief_cov"].double()
    assert (cov - cov.mT).abs().max().item() < 1e-5 * cov.abs().max().item()
    assert torch.linalg.eigvalsh(cov).min().item() > 0
    logdet = td["next", "logdet_cov"].double()
    error = (logdet - torch.logdet(cov)).abs()  # float32 Cholesky against float64 LU
    assert error.max().item() < 2e-2 and error.mean().item() < 1e-4


def test_det_cap_freezes_unobserved_covariance():
    env = TargetTrackingEnv(load_env_config("empty1"), batch_size=1, seed=0)
    env.reset()
    env.state["robot_pose"] = torch.tensor([[50.0, 50.0, 0.0]])
    env.state["target_state"] = torch.tensor([[[30.0, 50.0, 0.0, 0.0]]])  # behind the robot
    env.state["belief_mean"] = torch.tensor([[[30.0, 50.0, 0.0, 0.0]]])
    logdets = []
    for _ in range(60):
        nxt = _step(env, [10])  # stand still
        assert not nxt["observed"].any()
        logdets.append(nxt["logdet_cov"].item())
    assert max(logdets) < math.log(1e6)
    assert logdets[-1] == pytest.approx(logdets[-20], abs=1e-6)  # frozen at the cap
    assert logdets[0] > 4 * math.log(30.0)  # but it grew from Sigma0 = 30 I first

    uncapped = TargetTrackingEnv(load_env_config("empty1", ["belief.det_cap=null"]), batch_size=1, seed=0)
    uncapped.reset()
    uncapped.state.update(env.state.select("robot_pose", "target_state"))
    for _ in range(60):
        last = _step(uncapped, [10])["logdet_cov"].item()
    assert last > math.log(1e6) + 1


def test_observed_target_shrinks_belief_and_reward_is_score_increment():
    env = TargetTrackingEnv(load_env_config("empty1"), batch_size=1, seed=0)
    env.reset()
    env.state["robot_pose"] = torch.tensor([[50.0, 50.0, 0.0]])
    env.state["target_state"] = torch.tensor([[[55.0, 51.0, 0.0, 0.0]]])
    nxt = _step(env, [10])
    assert nxt["observed"].all()
    assert nxt["logdet_cov"].item() < 4 * math.log(30.0) - 3
    assert nxt["reward"].item() == pytest.approx(-nxt["logdet_cov"].item())


# ----------------------------------------------------------- reset / seed
def test_partial_reset_touches_only_masked_worlds():
    env = TargetTrackingEnv(load_env_config("obstacles1"), batch_size=6, seed=0)
    td = env.reset()
    for _ in range(7):
        td = env.step(td.set("action", torch.randint(0, 12, (6,))))["next"]
    before = env.state.clone()
    mask = torch.tensor([True, False, True, False, False, False])
    after = env.reset(td.set("_reset", mask.unsqueeze(-1)))
    for key in ("robot_pose", "target_state", "belief_mean", "belief_cov"):
        assert torch.equal(after[key][~mask], before[key][~mask])
        assert not torch.equal(after[key][mask], before[key][mask])
    assert env._step_count.tolist() == [0, 7, 0, 7, 7, 7]
    assert torch.equal(after["belief_cov"][mask], 30.0 * torch.eye(4).expand(2, 1, 4, 4))


def test_a_worlds_stream_ignores_the_other_worlds():
    def second_episode(mask, batch_size):
        env = TargetTrackingEnv(load_env_config("obstacles1"), batch_size=batch_size, seed=11)
        td = env.reset()
        return env.reset(td.set("_reset", mask.unsqueeze(-1)))

    a = second_episode(torch.tensor([True, True, True, False]), 4)
    b = second_episode(torch.tensor([False, False, True, True, False]), 5)
    for key in ("robot_pose", "target_state", "belief_mean"):
        assert torch.equal(a[key][2], b[key][2])


def test_replay_streams_reproduces_later_episodes_of_a_smaller_env():
    small = TargetTrackingEnv(load_env_config("obstacles1"), batch_size=2, seed=3)
    episodes = [small.reset() for _ in range(3)]  # episodes 1, 2 and 3 of worlds 0 and 1
    big = TargetTrackingEnv(load_env_config("obstacles1"), batch_size=4, seed=99)
    big.replay_streams(3, worlds=torch.tensor([1, 0, 1, 0]), episodes=torch.tensor([2, 0, 0, 1]))
    replayed = big.reset()
    for b, (world, episode) in enumerate([(1, 2), (0, 0), (1, 0), (0, 1)]):
        for key in ("robot_pose", "target_state", "belief_mean"):
            assert torch.equal(replayed[key][b], episodes[episode][key][world])
    with pytest.raises(ValueError, match=r"episodes must be 4 non-negative integers.*\[0, -1, 0, 0\]"):
        big.replay_streams(3, torch.zeros(4, dtype=torch.int64), torch.tensor([0, -1, 0, 0]))
    with pytest.raises(ValueError, match="worlds must be 4"):
        big.replay_streams(3, torch.zeros(3, dtype=torch.int64), torch.zeros(4, dtype=torch.int64))


def test_replay_streams_with_one_seed_per_world_replays_several_envs_in_one():
    config = load_env_config("obstacles1")
    smalls = {seed: TargetTrackingEnv(config, batch_size=2, seed=seed) for seed in (3, 5)}
    episodes = {seed: [env.reset() for _ in range(3)] for seed, env in smalls.items()}  # episodes 1-3
    plan = [(3, 1, 2), (5, 0, 0), (5, 1, 1), (3, 0, 0)]  # (seed, world, episodes before) of each big world
    seeds, worlds, before = (torch.tensor(column) for column in zip(*plan, strict=True))
    big = TargetTrackingEnv(config, batch_size=4, seed=99)
    for given in (seeds, seeds.tolist()):  # a tensor or a list of seeds
        big.replay_streams(given, worlds=worlds, episodes=before)
        replayed = big.reset()
        for b, (seed, world, episode) in enumerate(plan):
            for key in ("robot_pose", "target_state", "belief_mean"):
                assert torch.equal(replayed[key][b], episodes[seed][episode][key][world]), (b, key)
    # one seed for every world is the same as that seed repeated
    big.replay_streams(3, worlds=worlds, episodes=before)
    one = big.reset()
    big.replay_streams([3] * 4, worlds=worlds, episodes=before)
    assert torch.equal(big.reset()["target_state"], one["target_state"])
    assert not torch.equal(one["target_state"], replayed["target_state"])
    with pytest.raises(ValueError, match=r"seed must be 4 non-negative integers.*\[3, -5, 5, 3\]"):
        big.replay_streams([3, -5, 5, 3], worlds=worlds, episodes=before)
    for bad in ([3, 5, 3], [1.7, 2.0, 3.0, 4.0]):  # one seed short; not integers
        with pytest.raises(ValueError, match="seed must be 4 non-negative integers"):
            big.replay_streams(bad, worlds=worlds, episodes=before)


def test_same_seed_same_rollout_and_batch_size_independence():
    def rollout(seed, batch_size):
        env = make_env("small2", batch_size=batch_size, seed=seed)
        generator = torch.Generator().manual_seed(0)
        actions = torch.randint(0, 12, (30, 5), generator=generator)[:, :batch_size]
        td = env.reset()
        poses = []
        for t in range(30):
            td = env.step(td.set("action", actions[t]))["next"]
            poses.append(td["observation"])
        return torch.stack(poses)

    first, again, other = rollout(4, 5), rollout(4, 5), rollout(5, 5)
    assert torch.equal(first, again)
    assert not torch.allclose(first, other)
    assert torch.equal(rollout(4, 2), first[:, :2])
    # each world has its own stream
    assert not torch.allclose(first[:, 0], first[:, 1])


def test_truncation_after_max_steps():
    env = make_env("empty1", batch_size=2, seed=0, overrides=["max_steps=7"])
    td = env.rollout(7)
    assert td["next", "truncated"].squeeze(-1).tolist() == [[False] * 6 + [True]] * 2
    assert torch.equal(td["next", "done"], td["next", "truncated"])
    assert not td["next", "terminated"].any()


def test_compiled_step_matches_eager():
    eager = make_env("obstacles1", batch_size=4, seed=9)
    compiled = make_env("obstacles1", batch_size=4, seed=9, compile=True)
    actions = torch.randint(0, 12, (12, 4), generator=torch.Generator().manual_seed(1))
    tds = [eager.reset(), compiled.reset()]
    for t in range(12):
        tds = [env.step(td.set("action", actions[t]))["next"] for env, td in zip((eager, compiled), tds, strict=True)]
        assert torch.allclose(tds[0]["observation"], tds[1]["observation"], rtol=1e-4, atol=1e-4)


# ---------------------------------------------------------------- errors
def test_unknown_setting_and_map_errors():
    with pytest.raises(ValueError, match="env='nowhere'.*empty1"):
        make_env("nowhere")
    with pytest.raises(ValueError, match="env.map='atlantis'.*obstacles4"):
        make_env("empty1", overrides=["map=atlantis"])


def test_bad_sizes_and_fields_are_named():
    with pytest.raises(ValueError, match="num_targets=0"):
        make_env("empty1", overrides=["num_targets=0"])
    with pytest.raises(ValueError, match="batch_size=0"):
        make_env("empty1", batch_size=0)
    with pytest.raises(ValueError, match="batch_size=-3"):
        TargetTrackingEnv(TrackingConfig(), batch_size=-3)
    with pytest.raises(ValueError, match="sensr"):
        make_env("empty1", overrides=["sensr.range=3"])
    with pytest.raises(ValueError, match="init_offset_shape='ring'.*disk"):
        make_env("empty1", overrides=["belief.init_offset_shape=ring"])


def test_action_out_of_range_is_named():
    env = make_env("empty1", batch_size=2, seed=0)
    td = env.reset()
    with pytest.raises(ValueError, match="action 12 is out of range.*0..11"):
        env.step(td.set("action", torch.tensor([3, 12])))
    with pytest.raises(ValueError, match="action -1 is out of range"):
        env.step(td.set("action", torch.tensor([-1, 0])))


def test_map_file_with_wrong_grid_shape(tmp_path):
    import numpy as np

    np.save(tmp_path / "grid.npy", np.zeros((10, 12)))
    (tmp_path / "box.yaml").write_text("size: [5.0, 5.0]\nresolution: 0.5\ngrid: grid.npy\n")
    with pytest.raises(ValueError, match=r"shape \[10, 12\].*\[10, 10\]"):
        make_env("empty1", overrides=[f"map={tmp_path / 'box.yaml'}"])


def test_user_map_from_file(tmp_path):
    (tmp_path / "room.yaml").write_text(
        "size: [20.0, 10.0]\nresolution: 0.5\nrobot_start: [3.0, 5.0]\nboxes:\n  - [9.0, 0.0, 11.0, 6.0]\n"
    )
    env = make_env("empty1", batch_size=8, seed=0, overrides=[f"map={tmp_path / 'room.yaml'}", "max_steps=20"])
    td = env.rollout(20)
    assert torch.equal(td["robot_pose"][:, 0, :2], torch.tensor([3.0, 5.0]).expand(8, 2))
    assert (td["next", "robot_pose"][..., 0] <= 19.5).all()


# ------------------------------------------------------- other models
@pytest.mark.parametrize("setting, size, dim", [("ttenv_v2", 4, 3), ("ttenv_v3", 6, 5)])
def test_ttenv_presets_specs_and_layout(setting, size, dim):
    env = make_env(setting, batch_size=3, seed=0, overrides=["num_targets=2"])
    check_env_specs(env, seed=0)
    td = env.rollout(4)
    assert td["next", "observation"].shape == (3, 4, 2 * size + 2)
    assert td["next", "belief_cov"].shape == (3, 4, 2, dim, dim)
    has_velocity = ("next", "belief_velocity") in td.keys(True)
    assert has_velocity == (size == 6)
    observation = td["next", "observation"]
    assert torch.equal(observation[..., size - 2:2 * size:size], td["next", "logdet_cov"])


@pytest.mark.parametrize("overrides", [
    ["target.model=se2_sine", "belief.filter=ukf"],
    ["target.model=se2_constant", "belief.filter=ukf", "belief.model=double_integrator"],
])
def test_other_models_keep_a_world_independent_of_the_batch(overrides):
    def rollout(batch_size):
        env = make_env("small2", batch_size=batch_size, seed=4, overrides=overrides)
        actions = torch.randint(0, 12, (20, 5), generator=torch.Generator().manual_seed(0))[:, :batch_size]
        td, out = env.reset(), []
        for t in range(20):
            td = env.step(td.set("action", actions[t]))["next"]
            out.append(torch.cat((td["observation"], td["target_state"].flatten(-2)), -1))
        return torch.stack(out)

    assert torch.equal(rollout(2), rollout(5)[:, :2])


def test_robot_anchored_start_places_beliefs_then_targets():
    env = make_env("ttenv_v2", batch_size=256, seed=1, transforms=False)
    td = env.reset()
    robot = td["robot_pose"][:, None, :2]
    belief_xy, target_xy = td["belief_mean"][..., :2], td["target_state"][..., :2]
    distance = torch.linalg.vector_norm(belief_xy - robot, dim=-1)
    assert distance.min() >= 5.0 - 1e-4 and distance.max() <= 20.0 + 1e-4
    away = belief_xy - robot
    offset = target_xy - belief_xy
    cosine = (away * offset).sum(-1) / (away.norm(dim=-1) * offset.norm(dim=-1)).clamp_min(1e-9)
    assert (cosine >= -1e-4).all() and offset.norm(dim=-1).max() <= 20.0 + 1e-4   # within +-pi/2 of "away"
    # a belief's heading points away from the robot, a target's away from its belief
    assert torch.allclose(td["belief_mean"][..., 2], torch.atan2(away[..., 1], away[..., 0]), atol=1e-5)
