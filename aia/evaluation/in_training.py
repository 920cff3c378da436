"""``Evaluator``: the training loop's evaluations (SPEC 9) of every member, several played in one rollout.

An evaluation is ``E`` episodes of a member's current policy at a small epsilon, one per world of an
evaluation env. The paper evaluates after every training episode, and a rollout of ``E`` worlds costs about
as much as one of ``G * P * E``: per-step overhead, not arithmetic, dominates at these sizes. So
:meth:`Evaluator.add` only snapshots the members' stacked parameters, and once ``G`` evaluations are pending
:meth:`Evaluator.flush` plays them together for all ``P`` members in an env of ``G * P * E`` worlds with a
:class:`~aia.modules.SnapshotPolicy`.

Evaluation ``n`` (0-based, counted over the whole run) of member ``k`` is the same whatever ``G`` and ``P``
are and whenever it is played: its worlds replay episode ``n + 1`` of the ``E`` worlds of an env seeded with
``seeds[k]`` (:meth:`~aia.envs.TargetTrackingEnv.replay_streams`), and its epsilon-greedy noise comes from
the counter-based stream of ``noise_seeds[k] + n``. Only float rounding of the batched network can differ.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor
from torchrl.envs import EnvBase

from aia.evaluation.rollouts import run_episodes
from aia.evaluation.scores import evaluation_summary
from aia.logging import SceneRecorder
from aia.modules import SnapshotPolicy, StackedConvQNetwork, StackedQNetwork, parameter_snapshot


@dataclass
class EvaluationPoint:
    """Where an evaluation was asked for: its index in the run, the training episodes and frames so far."""

    index: int
    episode: int
    frame: int
    params: dict[str, Tensor]


class Evaluator:
    """Plays the evaluations asked for by :meth:`add`, ``per_rollout`` at a time, for every member.

    Args:
        env: the evaluation env; its batch holds ``per_rollout`` groups of ``P`` members of ``episodes`` worlds.
        network: the members' stacked Q-network being trained (ADFQ acts greedily on its means), a conv network
            reading the env's map image too (a ``local_map`` key).
        num_actions: size of the discrete action space.
        episodes: episodes per evaluation (``E``).
        epsilon: the evaluation's epsilon.
        seeds: each member's seed of its evaluation worlds.
        noise_seeds: member ``k``'s evaluation ``n`` draws its epsilon-greedy noise from ``noise_seeds[k] + n``.
        first_index: index of the next evaluation (the count so far, when a run resumes).
        recorders: one per member or none: records the member's world 0 of every ``record_every``-th
            evaluation (0: never), labelled with its training episode and frame; at most one per rollout, so
            ``per_rollout <= record_every``.
        compile: compile the snapshots' batched network (:class:`~aia.modules.SnapshotPolicy`).
    """

    def __init__(self, env: EnvBase, network: StackedQNetwork | StackedConvQNetwork, num_actions: int, episodes: int,
                 epsilon: float, seeds: Sequence[int], noise_seeds: Sequence[int], first_index: int = 0,
                 recorders: Sequence[SceneRecorder] | None = None, record_every: int = 0,
                 compile: bool = False) -> None:
        worlds, members = env.batch_size[0], network.num_members
        if len(seeds) != members or len(noise_seeds) != members:
            raise ValueError(f"need one seed and one noise seed per member ({members}), got {list(seeds)} and "
                             f"{list(noise_seeds)}")
        if episodes < 1 or worlds % (episodes * members):
            raise ValueError(f"the evaluation env's {worlds} worlds do not split into groups of {members} members "
                             f"x episodes={episodes}")
        self.per_rollout = worlds // (episodes * members)
        if recorders and record_every > 0 and self.per_rollout > record_every:
            raise ValueError(f"{self.per_rollout} evaluations per rollout would record several episodes at once: "
                             f"the number per rollout must be at most record_every={record_every}")
        self.env = env
        self.network = network
        self.episodes = episodes
        self.seeds = list(seeds)
        self.noise_seeds = list(noise_seeds)
        self.next_index = first_index
        self.recorders = list(recorders) if recorders and record_every > 0 else []
        self.record_every = record_every
        self.policy = SnapshotPolicy(network, num_actions, epsilon, compile=compile)
        self.pending: list[EvaluationPoint] = []

    @property
    def full(self) -> bool:
        """Whether ``per_rollout`` evaluations are pending (time to :meth:`flush`)."""
        return len(self.pending) >= self.per_rollout

    def add(self, episode: int, frame: int) -> None:
        """Ask for an evaluation of every member's network as it is now, after ``episode`` training episodes
        and ``frame`` frames."""
        self.pending.append(EvaluationPoint(self.next_index, episode, frame, parameter_snapshot(self.network)))
        self.next_index += 1

    def flush(self) -> list[tuple[EvaluationPoint, list[dict]]]:
        """Play the pending evaluations, ``per_rollout`` per rollout; each with one
        :func:`~aia.evaluation.scores.evaluation_summary` per member, in the order they were asked for."""
        points, self.pending = self.pending, []
        results = []
        for start in range(0, len(points), self.per_rollout):
            results += self._play(points[start:start + self.per_rollout])
        return results

    def _play(self, points: list[EvaluationPoint]) -> list[tuple[EvaluationPoint, list[dict]]]:
        """One rollout. Unused groups of the batch replay the last evaluation (the env's shape stays fixed,
        so a compiled env does not recompile) and are dropped."""
        padded = points + [points[-1]] * (self.per_rollout - len(points))
        E, P = self.episodes, len(self.seeds)
        groups = len(padded) * P
        worlds = torch.arange(E).repeat(groups)
        episodes = torch.tensor([p.index for p in padded]).repeat_interleave(P * E)
        seeds = torch.tensor(self.seeds).repeat_interleave(E).repeat(len(padded))
        base_env = self.env.base_env if hasattr(self.env, "base_env") else self.env
        base_env.replay_streams(seeds, worlds, episodes)
        self.policy.load([p.params for p in padded], [[s + p.index for s in self.noise_seeds] for p in padded])
        recorded = [g for g, p in enumerate(points) if p.index % self.record_every == 0] if self.recorders else []
        if recorded:
            for member, recorder in enumerate(self.recorders):
                recorder.world = (recorded[0] * P + member) * E
                recorder.record(episode=points[recorded[0]].episode, frame=points[recorded[0]].frame)
        rollout = run_episodes(self.env, self.policy)
        summaries = [evaluation_summary(rollout[g * E:(g + 1) * E]) for g in range(len(points) * P)]
        return [(p, summaries[g * P:(g + 1) * P]) for g, p in enumerate(points)]
