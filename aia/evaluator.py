"""``Evaluator``: the training loop's evaluations (SPEC 9), several played in one batched rollout.

An evaluation is ``E`` episodes of the current policy at a small epsilon, one per world of an evaluation
env. The paper evaluates after every training episode, and a rollout of ``E`` worlds costs about as much as
one of ``G * E``: per-step overhead, not arithmetic, dominates at these sizes. So :meth:`Evaluator.add`
only snapshots the network's parameters, and once ``G`` evaluations are pending :meth:`Evaluator.flush`
plays them together in an env of ``G * E`` worlds with a :class:`~aia.modules.SnapshotPolicy`.

Evaluation ``n`` (0-based, counted over the whole run) is the same whatever ``G`` is and whenever it is
played: its worlds replay episode ``n + 1`` of the ``E`` worlds of an env seeded with ``seed``
(:meth:`~aia.envs.TargetTrackingEnv.replay_streams`), and its epsilon-greedy noise comes from a generator
seeded with ``noise_seed + n``. Only float rounding of the batched network can differ.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torchrl.envs import EnvBase

from aia.evaluation import evaluation_summary, run_episodes
from aia.logging import SceneRecorder
from aia.modules import SnapshotPolicy, parameter_snapshot


@dataclass
class EvaluationPoint:
    """Where an evaluation was asked for: its index in the run, the training episodes and frames so far."""

    index: int
    episode: int
    frame: int
    params: dict[str, Tensor]


class Evaluator:
    """Plays the evaluations asked for by :meth:`add`, ``per_rollout`` at a time.

    Args:
        env: the evaluation env; its batch holds ``per_rollout`` groups of ``episodes`` worlds.
        network: the Q-network being trained (the ADFQ network acts greedily on its means).
        num_actions: size of the discrete action space.
        episodes: episodes per evaluation (``E``).
        epsilon: the evaluation's epsilon.
        seed: seed of the evaluation worlds.
        noise_seed: evaluation ``n`` draws its epsilon-greedy noise from ``noise_seed + n``.
        first_index: index of the next evaluation (the count so far, when a run resumes).
        recorder: records world 0 of every ``record_every``-th evaluation (0: never), labelled with its
            training episode and frame; at most one per rollout, so ``per_rollout <= record_every``.
        compile: compile the snapshots' batched network (:class:`~aia.modules.SnapshotPolicy`).
    """

    def __init__(self, env: EnvBase, network: nn.Module, num_actions: int, episodes: int, epsilon: float,
                 seed: int, noise_seed: int, first_index: int = 0, recorder: SceneRecorder | None = None,
                 record_every: int = 0, compile: bool = False) -> None:
        worlds = env.batch_size[0]
        if episodes < 1 or worlds % episodes:
            raise ValueError(f"the evaluation env's {worlds} worlds do not split into groups of episodes={episodes}")
        self.per_rollout = worlds // episodes
        if recorder is not None and record_every > 0 and self.per_rollout > record_every:
            raise ValueError(f"{self.per_rollout} evaluations per rollout would record several episodes at once: "
                             f"the number per rollout must be at most record_every={record_every}")
        self.env = env
        self.network = network
        self.episodes = episodes
        self.seed = seed
        self.noise_seed = noise_seed
        self.next_index = first_index
        self.recorder = recorder if record_every > 0 else None
        self.record_every = record_every
        self.policy = SnapshotPolicy(network, num_actions, epsilon, compile=compile)
        self.pending: list[EvaluationPoint] = []

    @property
    def full(self) -> bool:
        """Whether ``per_rollout`` evaluations are pending (time to :meth:`flush`)."""
        return len(self.pending) >= self.per_rollout

    def add(self, episode: int, frame: int) -> None:
        """Ask for an evaluation of the network as it is now, after ``episode`` training episodes and
        ``frame`` frames."""
        self.pending.append(EvaluationPoint(self.next_index, episode, frame, parameter_snapshot(self.network)))
        self.next_index += 1

    def flush(self) -> list[tuple[EvaluationPoint, dict]]:
        """Play the pending evaluations, ``per_rollout`` per rollout; each with its
        :func:`~aia.evaluation.evaluation_summary`, in the order they were asked for."""
        points, self.pending = self.pending, []
        results = []
        for start in range(0, len(points), self.per_rollout):
            results += self._play(points[start:start + self.per_rollout])
        return results

    def _play(self, points: list[EvaluationPoint]) -> list[tuple[EvaluationPoint, dict]]:
        """One rollout. Unused groups of the batch replay the last evaluation (the env's shape stays fixed,
        so a compiled env does not recompile) and are dropped."""
        padded = points + [points[-1]] * (self.per_rollout - len(points))
        E = self.episodes
        worlds = torch.arange(E).repeat(self.per_rollout)
        episodes = torch.tensor([p.index for p in padded]).repeat_interleave(E)
        base_env = self.env.base_env if hasattr(self.env, "base_env") else self.env
        base_env.replay_streams(self.seed, worlds, episodes)
        self.policy.load([p.params for p in padded], [self.noise_seed + p.index for p in padded])
        if self.recorder is not None:
            recorded = [k for k, p in enumerate(points) if p.index % self.record_every == 0]
            if recorded:
                self.recorder.world = recorded[0] * E
                self.recorder.record(episode=points[recorded[0]].episode, frame=points[recorded[0]].frame)
        rollout = run_episodes(self.env, self.policy)
        return [(p, evaluation_summary(rollout[k * E:(k + 1) * E])) for k, p in enumerate(points)]
