"""aia.training.loop: every algorithm trains without NaN, checkpoints resume, bad configs are named."""

from __future__ import annotations

import math

import pytest
import torch
from hydra import compose, initialize_config_module

from aia.logging import read_run
from aia.training import make_actor, progress, train, train_population


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


SMALL = ("env.max_steps=40", "warmup_frames=100", "logger=none", "eval.episodes=2", "batch_size=16")


def _assert_finished(state, cfg, out_dir, evaluations: int) -> None:
    """The counters of a run that trained ``cfg.frames`` frames in one world, finite scores and weights, and a
    checkpoint that holds the final counters and phase times."""
    assert state.frames == cfg.frames and state.episodes == cfg.frames // cfg.env.max_steps
    assert state.updates == cfg.frames - cfg.warmup_frames + 1  # one per frame from the warm-up's last on
    assert len(state.eval_scores) == evaluations and all(math.isfinite(s) for s in state.eval_scores)
    checkpoint = torch.load(out_dir / "checkpoints" / "last.pt", weights_only=False)
    assert checkpoint["state"]["frames"] == cfg.frames
    assert {"collect", "buffer", "update", "evaluate", "other"} <= set(state.seconds)
    assert all(seconds >= 0 for seconds in state.seconds.values())
    assert checkpoint["state"]["seconds"] == state.seconds
    for value in checkpoint["actor"].values():
        assert torch.isfinite(value).all()


# DQN and ADFQ with epsilon-greedy train in the other loop tests, ADFQ-TS in the learning test below; every
# loss's step is checked in test_optimizer
def test_double_dqn_trains_1000_frames_without_nan(tmp_path):
    cfg = _config("algo=ddqn", "frames=1000", "eval.every_episodes=5", *SMALL)
    sent: list[dict] = []
    with progress.forwarding(sent.append):
        state = train(cfg, tmp_path)
    _assert_finished(state, cfg, tmp_path, evaluations=5)
    # the last evaluation plays as the run ends (the first four play mid-run): the bar ends showing its score
    assert sent[-1]["closed"] and sent[-1]["postfix"].startswith(f"score={state.eval_scores[-1]:.0f},")


def test_collects_from_several_worlds_per_batch(tmp_path):
    cfg = _config("frames=400", "collector.num_envs=4", "updates_per_frame=0.25", *SMALL)
    state = train(cfg, tmp_path)
    # 4 worlds x 100 steps: two complete 40-step episodes each; one update per batch of 4 from frame 100 on
    assert state.frames == 400 and state.episodes == 8 and state.updates == 76


def test_resume_continues_the_counters(tmp_path):
    first = train(_config("frames=200", *SMALL), tmp_path / "a")
    resumed = train(_config("frames=320", f"resume={tmp_path / 'a' / 'checkpoints' / 'last.pt'}", *SMALL),
                    tmp_path / "b")
    assert first.frames == 200 and resumed.frames == 320
    assert resumed.updates == first.updates + 120
    assert resumed.eval_scores[: len(first.eval_scores)] == first.eval_scores
    assert all(resumed.seconds[phase] > first.seconds[phase] for phase in ("collect", "update", "other"))


def test_evaluations_per_rollout_change_nothing_but_speed(tmp_path):
    one_by_one = train(_config("frames=400", "eval.per_rollout=1", *SMALL), tmp_path / "a")
    together = train(_config("frames=400", "eval.per_rollout=3", *SMALL), tmp_path / "b")
    assert len(together.eval_scores) == 10 and together.evaluations == 10
    assert together.eval_scores == pytest.approx(one_by_one.eval_scores, rel=1e-5)
    assert together.updates == one_by_one.updates


def test_csv_logger_writes_the_curves(tmp_path):
    # a quarter of an update per frame: updates are owed across batches
    cfg = _config("frames=560", "updates_per_frame=0.25", "logger=csv",
                  *[o for o in SMALL if not o.startswith("logger")])
    state = train(cfg, tmp_path)
    assert state.updates == 115  # frames 100..560 at 0.25 per frame
    scalars = tmp_path / "csv" / "scalars"
    curve = (scalars / "eval" / "score.csv").read_text().strip().splitlines()
    assert len(curve) == 14  # one evaluation per 40-step training episode
    assert len((scalars / "train" / "loss.csv").read_text().strip().splitlines()) == 1  # every 100 updates


def test_mcap_logger_gets_scores_config_and_recorded_episodes(tmp_path):
    # 4 evaluations per rollout: the recorded ones (0, 5, 10) fall at different places of their rollouts
    cfg = _config("frames=560", "logger=mcap", "logger.record_every_evaluations=5", "eval.per_rollout=4",
                  *[o for o in SMALL if not o.startswith("logger")])
    state = train(cfg, tmp_path)
    run = read_run(tmp_path / "run.mcap")
    assert run.complete
    scores = run.scalars("eval/score")
    assert scores.values.tolist() == pytest.approx(state.eval_scores)
    assert scores.frames.tolist() == [40.0 * k for k in range(1, 15)]
    assert len(run.scalars("train/loss").values) == 4  # one per 100 updates
    errors = run.scalars("eval/belief_error")
    assert errors.frames.tolist() == scores.frames.tolist() and (errors.values > 0).all()
    for phase, seconds in state.seconds.items():
        assert run.scalars(f"time/{phase}_s").values.tolist() == pytest.approx([seconds])
    assert run.config_value("algo") == "dqn" and run.config_value("env.max_steps") == 40
    assert run.metadata["run"]["seed"] == "0"
    assert run.episodes() == [1, 6, 11]  # the first of every 5 evaluations, labelled by training episode
    info, frames = run.episode("last")
    assert info.frame == 440 and len(frames) == 41
    assert run.topic_counts()["/log"] == ("foxglove.Log", 14)


@pytest.mark.parametrize("switch", [False, True])
def test_compile_update_switch_decides_whether_the_step_is_compiled(tmp_path, monkeypatch, switch):
    # compile.update is also the name of DictConfig's dict method: reading the switch as an attribute
    # gave that (truthy) method, and every run compiled its optimiser step.
    import aia.training.optimizer as optimizer

    calls = []
    monkeypatch.setattr(optimizer, "compiled_update", lambda fn: calls.append(fn) or fn)
    train(_config("frames=120", f"compile.update={str(switch).lower()}", *SMALL), tmp_path)
    assert calls == ([optimizer.update_step] if switch else [])


def test_bad_configs_name_the_field(tmp_path):
    with pytest.raises(ValueError, match="exploration='thompson': expected egreedy with algo=dqn"):
        train(_config("exploration=thompson", *SMALL), tmp_path)
    with pytest.raises(ValueError, match="eval.per_rollout=6: expected at most logger.record_every_evaluations=5"):
        train(_config("eval.per_rollout=6", "logger=mcap", "logger.record_every_evaluations=5"), tmp_path)
    with pytest.raises(ValueError, match="collector.num_envs=0: expected an integer >= 1"):
        train(_config("collector.num_envs=0", *SMALL), tmp_path)


def test_adfq_thompson_learns_to_beat_random_and_its_initial_policy(tmp_path):
    """Seeded learning check on a short-horizon single-target setting, three seeds trained as one population
    (about a minute of CPU): one seed's outcome hangs on rounding (seed 1 alone passed this check, > 661, on
    the machine of the previous session and scored 635 on that of 2026-12-02 with the same commit; seeds 0, 2,
    3 scored 988, 890, 917), the mean of three much less."""
    from tensordict.nn import TensorDictSequential

    from aia.envs import make_env
    from aia.envs.factory import to_tracking_config
    from aia.evaluation import episode_scores, run_episodes
    from aia.modules import EpsilonGreedy
    from aia.policies import RandomPolicy

    seeds = (0, 1, 2)
    cfgs = [_config("algo=adfq", "exploration=thompson", "frames=2000", "env.max_steps=50", "logger=none",
                    "eval.every_episodes=10", f"seed={seed}") for seed in seeds]
    for seed, cfg, state in zip(seeds, cfgs, train_population(cfgs, [tmp_path / str(s) for s in seeds]), strict=True):
        _assert_finished(state, cfg, tmp_path / str(seed), evaluations=4)
    env = make_env(to_tracking_config(cfgs[0].env), batch_size=64, seed=123)

    def score(policy):
        return episode_scores(run_episodes(env, policy, seed=123)).mean().item()

    def semi_greedy(actor):
        return TensorDictSequential(actor, EpsilonGreedy(12, 0.05, 0.05, 1, seed=0))

    learned = []
    for seed in seeds:
        trained = make_actor(cfgs[0], env)
        checkpoint = torch.load(tmp_path / str(seed) / "checkpoints" / "last.pt", weights_only=False)
        trained.load_state_dict(checkpoint["actor"])
        learned.append(score(semi_greedy(trained)))
    untrained, random = score(semi_greedy(make_actor(cfgs[0], env))), score(RandomPolicy(12))
    # measured 2026-12-02: learned 988, 635, 890 (mean 838), untrained (all actions tied: always primitive 0) 611,
    # random 5
    assert min(learned) > random + 300, (learned, random)
    assert sum(learned) / len(learned) > untrained + 150, (learned, untrained)


@pytest.mark.parametrize("experiment, targets, hidden, lr, every", [
    ("paper_empty1", 1, 128, 1e-3, 1), ("paper_obstacles1", 1, 128, 1e-3, 1),
    ("paper_small2", 2, 256, 5e-4, 2), ("paper_small3", 3, 256, 5e-4, 2),
])
@pytest.mark.parametrize("algo", ["dqn", "ddqn", "adfq"])
def test_every_experiment_preset_composes(experiment, targets, hidden, lr, every, algo):
    cfg = _config(f"experiment={experiment}", f"algo={algo}")
    assert cfg.env.num_targets == targets and list(cfg.hidden) == [hidden] * 3 and cfg.lr == lr
    assert cfg.eval.every_episodes == every and cfg.batch_size == 64 and cfg.buffer_size == 1000
    # a command-line override still wins over the preset
    assert _config(f"experiment={experiment}", "lr=0.01").lr == 0.01
