"""Closed-form ADFQ posterior (Assumed Density Filtering Q-learning, Jeong & Lee 2017, arXiv 1712.03333).

The belief over Q(s, a) is N(mu, s^2); the TD target of next action b is r + gamma * N(mu'_b, s'_b^2). For each
candidate maximising next action b the current belief is multiplied by b's target (variance
gamma^2 s'_b^2 + noise), which gives N(bar_mu_b, bar_var_b) with evidence N(mu; r + gamma mu'_b, add_var_b). The
constraint that b's value exceeds every other action's is approximated by a piecewise quadratic penalty: the
other actions c whose target mean lies above the solution x pull it up with precision 1 / (gamma^2 s'_c^2), so
x = (bar_mu_b / bar_var_b + sum_c t_c / v_c) / (1 / bar_var_b + sum_c 1 / v_c) over the active set. The active set
is found by scanning the other actions in decreasing order of target mean and keeping the first set whose
solution lies in its interval. The candidates are mixed with the softmax of their log evidences and
moment-matched to one Gaussian. A terminal transition uses the target N(r, reward_var + noise) instead (a plain
Gaussian product). This follows ``posterior_adfq(..., batch=True)`` of the authors' code (coco66/ADFQ,
``classic_adfq/adfq_fun.py``) with ``scale_factor=1``, ``noise_c=0``, ``asymptotic=False``, as deep ADFQ calls it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.data.tensor_specs import TensorSpec
from torchrl.data.utils import _find_action_space
from torchrl.modules import QValueModule
from torchrl.objectives.common import LossModule
from torchrl.objectives.utils import ValueEstimators, distance_loss

__all__ = ["ADFQLoss", "adfq_posterior"]

# The reference's open ends of the first and the last interval of the scan.
_UPPER_END = 1e20
_LOWER_END = -1e20
_LOG_2PI = math.log(2.0 * math.pi)


def _prefix_sums(terms: Tensor) -> Tensor:
    """Sums of the first i terms along the last dim, for i = 0..n: ``[..., n]`` -> ``[..., n + 1]``.

    Rounded as numpy's ``np.sum`` of each prefix (the reference's sums): sequential below 8 terms; from 8 terms
    the first 8 are added as a pairwise tree and the rest sequentially (exact for prefixes of up to 15 terms,
    i.e. up to 16 actions; longer prefixes keep adding sequentially, numpy would use more accumulators). The
    scan's accept test compares these sums' quotient with interval ends, so near ties depend on the last bit.
    """
    zero = terms.new_zeros((*terms.shape[:-1], 1))
    head = torch.cumsum(terms[..., :7], dim=-1)
    if terms.shape[-1] < 8:
        return torch.cat([zero, head], dim=-1)
    r = terms[..., :8]
    tree = ((r[..., 0:1] + r[..., 1:2]) + (r[..., 2:3] + r[..., 3:4])) + (
        (r[..., 4:5] + r[..., 5:6]) + (r[..., 6:7] + r[..., 7:8])
    )
    tail = torch.cumsum(torch.cat([tree, terms[..., 8:]], dim=-1), dim=-1)
    return torch.cat([zero, head, tail], dim=-1)


def adfq_posterior(
    next_mean: Tensor,
    next_var: Tensor,
    mean: Tensor,
    var: Tensor,
    reward: Tensor | float,
    gamma: Tensor | float,
    done: Tensor | bool,
    noise: float = 0.0,
    var_min: float = 1e-20,
    reward_var: float = 1e-3,
) -> tuple[Tensor, Tensor]:
    """ADF posterior N(post_mean, post_var) of Q(s, a) after observing (r, s'), batched and vectorised.

    Args:
        next_mean, next_var: belief over Q(s', b) for every next action b, ``[..., A]``.
        mean, var: belief over Q(s, a) of the taken action, ``[...]``.
        reward: ``[...]`` (or a scalar). gamma: discount, a scalar or broadcastable to ``[...]``.
        done: terminal flags ``[...]`` (bool, or 0/1); a terminal target is N(reward, reward_var + noise).
        noise: extra variance added to every TD target's variance (the reference's ``noise``).
        var_min: floor of the posterior variance (the reference's ``varTH``).
        reward_var: variance of the terminal target (the reference's ``REW_VAR``).

    Returns:
        ``(post_mean, post_var)``, each ``[...]``, in the promoted dtype of the four belief tensors; the
        computation is done in float64 on the inputs' device. No Python loop over the batch or the actions.

    Choices where the reference is silent or fragile (documented deviations are marked):

    * Ties: the scan keeps the first (smallest) active set whose solution satisfies ``lower <= x <= upper``
      with the reference's closed comparisons and its ends +-1e20, so exact ties of all next actions give the
      same all-or-nothing active sets as the reference. Tied target means are scanned by decreasing index (the
      reference's ascending argsort, stable for 12 items in the numpy of its time, flipped) and the prefix sums
      are rounded as numpy's ``np.sum``, so knife-edge accept tests at near ties come out as in the reference.
    * Deviation: if rounding leaves no interval accepting its solution (a solution within an ulp of an
      interval end, e.g. a top other action with a tiny variance; about 0.3% of rows with sds log-uniform in
      [1e-5, 1e5]), the reference prints a warning and gives that candidate mean 0, variance 0 and log
      evidence 0, which then often dominates the mixture; here the active set whose solution violates its
      interval least is used.
    * The mixture variance is computed as ``sum_b w_b (var_b + (mu_b - mean)^2)``, equal to the reference's
      ``sum_b w_b var_b + sum_b w_b mu_b (mu_b - mean)`` but free of its cancellation for large means.
    * Evidences are exact log densities (no CDF terms: the reference's closed form uses none), so the
      computation stays finite for sds from 1e-5 to 1e5 and means around +-1e3 in float64.

    The result is meant as a regression target; call it under ``torch.no_grad()`` (it is differentiable, but
    the choice of active set and candidate is piecewise).
    """
    out_dtype = torch.promote_types(
        torch.promote_types(next_mean.dtype, next_var.dtype), torch.promote_types(mean.dtype, var.dtype)
    )
    f64 = torch.float64
    device = next_mean.device
    n_mean = next_mean.to(f64)
    n_var = next_var.to(f64)
    c_mean = mean.to(f64).unsqueeze(-1)  # [..., 1]
    c_var = var.to(f64).unsqueeze(-1)
    rew = torch.as_tensor(reward, dtype=f64, device=device)
    # a Python discount stays a Python number: a tensor made of it would be a host-to-device copy (on CUDA, a
    # sync every update); as a float64 operand it rounds the same
    gam = gamma if isinstance(gamma, (int, float)) else torch.as_tensor(gamma, dtype=f64, device=device).unsqueeze(-1)
    num_actions = n_mean.shape[-1]

    # TD targets of every next action and the Gaussian product of each with the current belief.
    t_mean = rew.unsqueeze(-1) + gam * n_mean  # [..., A]
    t_var = gam**2 * n_var
    t_var_noisy = t_var + noise
    bar_var = 1.0 / (1.0 / c_var + 1.0 / t_var_noisy)
    bar_mean = bar_var * (c_mean / c_var + t_mean / t_var_noisy)
    add_var = c_var + t_var_noisy
    t_mean, t_var, bar_var, bar_mean, add_var = torch.broadcast_tensors(t_mean, t_var, bar_var, bar_mean, add_var)

    # For candidate b (dim -2), the other actions in decreasing order of target mean (dim -1, A - 1 of them).
    # Ties in the reference's order: a stable ascending sort, flipped (tied actions by decreasing index).
    order = torch.sort(t_mean.flip(-1), dim=-1, descending=True, stable=True).indices
    order = num_actions - 1 - order
    rank = torch.argsort(order, dim=-1)  # position of each action in the sorted order
    k = torch.arange(num_actions - 1, device=device)
    pos = k + (k >= rank.unsqueeze(-1)).long()  # [..., A, A-1]: sorted position of the k-th other of b
    other_idx = torch.gather(order.unsqueeze(-2).expand(*order.shape, num_actions), -1, pos)
    expand = (*t_mean.shape, num_actions)
    o_mean = torch.gather(t_mean.unsqueeze(-2).expand(expand), -1, other_idx)  # [..., A, A-1]
    o_var = torch.gather(t_var.unsqueeze(-2).expand(expand), -1, other_idx)

    # Step i of the scan makes the i largest others active: solution x_i and its interval [lower_i, upper_i].
    zero = o_mean.new_zeros((*o_mean.shape[:-1], 1))
    sum_mean = _prefix_sums(o_mean / o_var)  # [..., A, A]
    sum_prec = _prefix_sums(1.0 / o_var)
    bm = bar_mean.unsqueeze(-1)
    bv = bar_var.unsqueeze(-1)
    x = (sum_mean + bm / bv) / (1.0 / bv + sum_prec)
    lower = torch.cat([o_mean, torch.full_like(zero, _LOWER_END)], dim=-1)
    upper = torch.cat([torch.full_like(zero, _UPPER_END), o_mean], dim=-1)
    # Zero exactly where the reference accepts; argmin then picks the first accepted step (or the least bad).
    violation = torch.clamp_min(lower - x, 0.0) + torch.clamp_min(x - upper, 0.0)
    step = torch.argmin(violation, dim=-1, keepdim=True)  # [..., A, 1]

    mu_star = torch.gather(x, -1, step).squeeze(-1)  # [..., A]
    var_star = 1.0 / (1.0 / bar_var + torch.gather(sum_prec, -1, step).squeeze(-1))
    active = k < step  # [..., A, A-1]
    pull = torch.where(active, (o_mean - mu_star.unsqueeze(-1)) ** 2 / o_var, 0.0).sum(-1)
    log_k = 0.5 * (torch.log(var_star) - torch.log(bar_var) - _LOG_2PI - torch.log(add_var)) - 0.5 * (
        (t_mean - c_mean) ** 2 / add_var + (mu_star - bar_mean) ** 2 / bar_var + pull
    )

    # Moment-matched mixture of the candidates.
    weights = torch.softmax(log_k, dim=-1)
    post_mean = (weights * mu_star).sum(-1)
    post_var = (weights * (var_star + (mu_star - post_mean.unsqueeze(-1)) ** 2)).sum(-1)

    # Terminal transitions: N(mu, s^2) x N(r, reward_var + noise).
    c_mean = c_mean.squeeze(-1)
    c_var = c_var.squeeze(-1)
    term_var_t = reward_var + noise
    term_var = 1.0 / (1.0 / c_var + 1.0 / term_var_t)
    term_mean = term_var * (c_mean / c_var + rew / term_var_t)
    is_done = torch.as_tensor(done, device=device) != 0
    post_mean = torch.where(is_done, term_mean, post_mean)
    post_var = torch.where(is_done, term_var, post_var).clamp_min(var_min)
    return post_mean.to(out_dtype), post_var.to(out_dtype)


class ADFQLoss(LossModule):
    """Deep ADFQ loss (the authors' ``deep_adfq``), a TorchRL ``LossModule`` with DQNLoss's conventions.

    The value network is the ADFQ actor of :func:`aia.modules.make_qvalue_actor` (``adfq=True``), or any
    ``TensorDictModule`` writing ``action_value`` (means) and ``action_log_sd`` (log sds) per action. It is
    made functional with a separate copy of target parameters (``delay_value=True``), so TorchRL's
    ``HardUpdate(loss, value_network_update_interval=50)`` / ``SoftUpdate`` drive it as they drive ``DQNLoss``.

    For a batch of transitions (any batch shape) the target of the taken action ``a`` is computed without
    gradients, as in the reference (``deep_adfq/deepadfq.py``, ``learn``, the lines after ``q_target_vals``):

    * the current belief N(mu_{s,a}, s_{s,a}^2) from the TARGET parameters at ``s``;
    * the next beliefs N(mu_{s',b}, s_{s',b}^2) of every action ``b`` from the TARGET parameters at ``s'``;
    * both sds clipped to ``[sqrt(var_min), sd_max]`` (``sdMin = sqrt(varth)``, ``sdMax = 1e5``);
    * the posterior ``(post_mean, post_var) = adfq_posterior(...)`` with ``noise``, ``var_min`` as ``varTH``,
      and ``done`` = the ``terminated`` flag (a time-limit truncation is not terminal: the reference stores
      ``float(not done)``, i.e. 0, when the time limit ends the episode).

    The loss (``deep_adfq/build_graph.py``, ``build_train``) is, per sample,
    ``huber(mean_pred - post_mean) + huber(rho_pred - (-log sqrt(post_var)))`` with ``rho = -log sd`` of the
    ONLINE network at ``(s, a)`` (its log sd clipped to the same bounds, which stops the gradient outside
    them, like the reference's ``tf.clip_by_value``), Huber with delta 1 (``loss_function="smooth_l1"``), then
    averaged over the batch (weighted by ``priority_weight`` when present, TorchRL's convention:
    ``sum(w l) / sum(w)``; the reference uses ``mean(w l)``).

    Keyword Args:
        gamma: discount. noise: extra variance of every TD target (1.0 in the reference's tracking script).
        var_min: the reference's ``varth``: posterior variance floor, and ``sqrt(var_min)`` is the sd floor.
        reward_var: variance of a terminal target. sd_max: the sd ceiling (``sdMax``).
        loss_function: ``"smooth_l1"`` (the reference's Huber), ``"l2"`` or ``"l1"``.
        delay_value: keep separate target parameters (``False``: the target uses the detached online ones).
        action_space: ``"categorical"`` or ``"one-hot"`` (or a spec); read from the network's ``QValueModule``
            when omitted, else ``"categorical"``.
        reduction: ``"mean"`` (default), ``"sum"`` or ``"none"``.

    ``forward`` returns ``loss`` (scalar) and detached diagnostics ``td_error`` (mean |mean error|),
    ``sd_error`` (mean |-log sd error|) and ``posterior_sd`` (mean posterior sd); it writes the priority
    ``|mean error| + |-log sd error|`` (the reference's prioritized-replay priority) shaped ``[..., 1]`` into
    the input tensordict at the ``priority`` key.
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (``loss.set_keys(name=key)``).

        Attributes:
            action_value: per-action means written by the value network. Defaults to ``"action_value"``.
            action_log_sd: per-action log sds written by the value network. Defaults to ``"action_log_sd"``.
            action: the taken action (index or one-hot). Defaults to ``"action"``.
            priority: where the replay priority is written in the input. Defaults to ``"td_error"``.
            reward: reward key under ``"next"``. Defaults to ``"reward"``.
            done: done key under ``"next"`` (read for in_keys only). Defaults to ``"done"``.
            terminated: terminal key under ``"next"``, the posterior's ``done``. Defaults to ``"terminated"``.
            priority_weight: importance weights of a prioritized sampler. Defaults to ``"priority_weight"``.
            target_mean: a precomputed posterior mean (:meth:`target_posterior`), used instead of computing it.
                Defaults to ``"target_mean"``.
            target_var: its posterior variance. Defaults to ``"target_var"``.
        """

        action_value: NestedKey = "action_value"
        action_log_sd: NestedKey = "action_log_sd"
        action: NestedKey = "action"
        priority: NestedKey = "td_error"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        priority_weight: NestedKey = "priority_weight"
        target_mean: NestedKey = "target_mean"
        target_var: NestedKey = "target_var"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    default_value_estimator = ValueEstimators.TD0
    out_keys = ["loss", "td_error", "sd_error", "posterior_sd"]

    value_network: TensorDictModuleBase
    value_network_params: TensorDictParams
    target_value_network_params: TensorDictParams

    def __init__(
        self,
        value_network: TensorDictModuleBase,
        *,
        gamma: float = 0.99,
        noise: float = 1.0,
        var_min: float = 1e-10,
        reward_var: float = 1e-3,
        sd_max: float = 1e5,
        loss_function: str = "smooth_l1",
        delay_value: bool = True,
        action_space: str | TensorSpec | None = None,
        reduction: str = "mean",
    ) -> None:
        if not isinstance(value_network, TensorDictModuleBase):
            raise TypeError(
                "value_network must be a TensorDictModule(-like) writing action_value and action_log_sd, "
                f"got {type(value_network).__name__}"
            )
        if loss_function not in ("smooth_l1", "l2", "l1"):
            raise ValueError(f"loss_function must be 'smooth_l1', 'l2' or 'l1', got {loss_function!r}")
        super().__init__()
        self._in_keys: list[NestedKey] | None = None
        self.delay_value = delay_value
        self.convert_to_functional(value_network, "value_network", create_target_params=delay_value)
        self.value_network_in_keys = list(value_network.in_keys)
        if action_space is None:
            action_space = next(
                (m.action_space for m in value_network.modules() if isinstance(m, QValueModule)), "categorical"
            )
        self.action_space = _find_action_space(action_space)
        if self.action_space not in ("categorical", "one_hot"):
            raise ValueError(f"ADFQLoss supports categorical and one-hot actions, got {self.action_space!r}")
        self.gamma = float(gamma)
        self.noise = float(noise)
        self.var_min = float(var_min)
        self.reward_var = float(reward_var)
        self.sd_max = float(sd_max)
        self.log_sd_min = 0.5 * math.log(var_min)
        self.log_sd_max = math.log(sd_max)
        self.loss_function = loss_function
        self.reduction = reduction

    # ------------------------------------------------------------------ keys
    def _set_in_keys(self) -> None:
        keys = [
            self.tensor_keys.action,
            ("next", self.tensor_keys.reward),
            ("next", self.tensor_keys.done),
            ("next", self.tensor_keys.terminated),
            *self.value_network.in_keys,
            *[("next", key) for key in self.value_network.in_keys],
        ]
        self._in_keys = list(dict.fromkeys(keys))

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys ``forward`` reads."""
        if self._in_keys is None:
            self._set_in_keys()
        return self._in_keys

    def make_value_estimator(self, value_type: ValueEstimators | None = None, **hyperparams: float) -> None:
        """ADFQ builds its own target (no value estimator); this only accepts ``gamma`` (like DQNLoss's call)."""
        if value_type not in (None, ValueEstimators.TD0):
            raise NotImplementedError(f"ADFQLoss has its own ADF target; value_type {value_type} is not supported")
        unknown = set(hyperparams) - {"gamma"}
        if unknown:
            raise TypeError(f"unsupported hyperparameters {sorted(unknown)} (only gamma)")
        if "gamma" in hyperparams:
            self.gamma = float(hyperparams["gamma"])

    # --------------------------------------------------------------- helpers
    def _select_action(self, values: Tensor, action: Tensor) -> Tensor:
        """The entry of the taken action: ``[..., A]`` -> ``[...]``."""
        if self.action_space == "categorical":
            if action.ndim != values.ndim:
                action = action.unsqueeze(-1)
            return torch.gather(values, -1, action.long()).squeeze(-1)
        return (values * action.to(values.dtype)).sum(-1)

    def _clip_log_sd(self, log_sd: Tensor) -> Tensor:
        return log_sd.clamp(self.log_sd_min, self.log_sd_max)

    @staticmethod
    def _per_sample(x: Tensor, batch_size: torch.Size) -> Tensor:
        """A ``[..., 1]`` (or ``[...]``) per-transition entry as ``[...]`` (the batch shape)."""
        return x.reshape(batch_size)

    def target_posterior(self, tensordict: TensorDictBase, target_params: TensorDictBase | None = None
                         ) -> tuple[Tensor, Tensor]:
        """The ADF posterior ``(post_mean, post_var)`` (each the batch shape) that ``forward`` regresses onto.

        Computed without gradients from the target parameters at ``s`` (the taken action's belief) and ``s'``
        (every next action's belief), sds clipped to ``[sqrt(var_min), sd_max]``, ``done`` = ``terminated``.
        ``target_params`` stands in for ``target_value_network_params`` (e.g. the same values cast to the dtypes
        their layers multiply in, once for many calls).
        """
        in_keys = self.value_network.in_keys
        # s and s' side by side in a last batch dim (a leading dim would break a member-stacked network)
        both = torch.stack([tensordict.select(*in_keys), tensordict.get("next").select(*in_keys)],
                           dim=tensordict.batch_dims)
        means, log_sds = self.target_beliefs(both, target_params)
        return self.posterior_of_beliefs(tensordict, (means[..., 0, :], log_sds[..., 0, :]),
                                         (means[..., 1, :], log_sds[..., 1, :]))

    def target_beliefs(self, observations: TensorDictBase, target_params: TensorDictBase | None = None
                       ) -> tuple[Tensor, Tensor]:
        """The target network's beliefs at ``observations`` (the value network's in_keys, any batch shape):
        every action's mean and log sd (clipped to the sd bounds), each ``[..., A]``, without gradients.
        ``target_params`` as in :meth:`target_posterior`."""
        if target_params is None:
            target_params = self.target_value_network_params
        keys = self.tensor_keys
        with torch.no_grad(), target_params.to_module(self.value_network, preserve_module_state=False):
            beliefs = self.value_network(observations.select(*self.value_network.in_keys))
        return beliefs.get(keys.action_value), self._clip_log_sd(beliefs.get(keys.action_log_sd))

    def posterior_of_beliefs(self, tensordict: TensorDictBase, beliefs: tuple[Tensor, Tensor],
                             next_beliefs: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor]:
        """:meth:`target_posterior` of the transitions ``tensordict`` (its action, next reward and terminated
        flag) from the target beliefs (:meth:`target_beliefs`) at their ``s`` and ``s'``, each ``[..., A]``."""
        keys = self.tensor_keys
        batch_size = tensordict.batch_size
        with torch.no_grad():
            action = tensordict.get(keys.action)
            mean = self._select_action(beliefs[0], action)
            var = torch.exp(2.0 * self._select_action(beliefs[1], action))
            next_mean = next_beliefs[0]
            next_var = torch.exp(2.0 * next_beliefs[1])
            reward = self._per_sample(tensordict.get(("next", keys.reward)), batch_size)
            terminated = self._per_sample(tensordict.get(("next", keys.terminated)), batch_size)
            return adfq_posterior(
                next_mean,
                next_var,
                mean,
                var,
                reward,
                self.gamma,
                terminated,
                noise=self.noise,
                var_min=self.var_min,
                reward_var=self.reward_var,
            )

    # --------------------------------------------------------------- forward
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """The ADFQ loss of a batch of transitions.

        Args:
            tensordict: transitions with the value network's in_keys at the root and under ``"next"``, the
                ``action``, and ``("next", reward | terminated | done)`` shaped ``[..., 1]`` (or ``[...]``);
                with ``target_mean`` and ``target_var`` (precomputed :meth:`target_posterior`), those are the
                targets and the target network is not run.

        Returns:
            ``TensorDict(loss=..., td_error=..., sd_error=..., posterior_sd=...)`` (scalars; only ``loss``
            carries gradients, to the online parameters).
        """
        keys = self.tensor_keys
        if keys.target_mean in tensordict.keys():  # noqa: SIM118 (TensorDict has no __contains__); precomputed
            post_mean, post_var = tensordict.get(keys.target_mean), tensordict.get(keys.target_var)
        else:
            post_mean, post_var = self.target_posterior(tensordict)
        td_online = tensordict.select(*self.value_network.in_keys)
        with self.value_network_params.to_module(self.value_network, preserve_module_state=False):
            td_online = self.value_network(td_online)
        action = tensordict.get(keys.action)
        pred_mean = self._select_action(td_online.get(keys.action_value), action)
        pred_rho = -self._clip_log_sd(self._select_action(td_online.get(keys.action_log_sd), action))
        target_rho = -0.5 * torch.log(post_var)
        loss = distance_loss(pred_mean, post_mean, self.loss_function) + distance_loss(
            pred_rho, target_rho, self.loss_function
        )
        with torch.no_grad():
            mean_error = (pred_mean - post_mean).abs()
            sd_error = (pred_rho - target_rho).abs()
            priority = (mean_error + sd_error).unsqueeze(-1)
        if tensordict.device is not None:
            priority = priority.to(tensordict.device)
        tensordict.set(keys.priority, priority, inplace=True)
        weights = self._maybe_get_priority_weight(tensordict)
        loss = self._reduce_loss(loss, tensordict=tensordict, weights=weights)
        td_out = TensorDict(
            loss=loss,
            td_error=mean_error.mean(),
            sd_error=sd_error.mean(),
            posterior_sd=post_var.detach().sqrt().mean(),
        )
        self._clear_weakrefs(tensordict, td_out, "value_network_params", "target_value_network_params")
        return td_out
