"""Empirical check of Theorem 1 and Corollary 1 (paper III.E, Eqs. 13–14, appendix).

Theorem 1: if D_KL(q_φS(c_T|s_S,a_S) || q_φT(c_S|s_T,a_T)) ≤ δ, R'_S(c) ∈ [a, b] and
|R'_T(c) − R'_S(c)| ≤ m, then

    |E_{π_T} R'_T − E_{π_S} R'_S| ≤ m + (b − a)/2 · √(2δ)                     (Eq. 13)

and for returns with discount γ (Corollary 1, Eq. 14; Eq. 26 for a finite horizon n)

    |E J_T − E J_S| ≤ (1/(1−γ)) [m + (b − a)/2 · √(2δ)]   (Σ_{t≤n} γ^t instead of 1/(1−γ)).

The hypotheses are stated for all pairs and all c; here they are estimated from rollouts
of the source and the transferred target policy on the target task:

* pairs: episode ``e`` of both agents starts from seed ``seed + e`` on the same task
  instance (the source's ``match_keys`` task parameters are given to the target), and
  target step t is matched to the source step of that episode the source bank gives it
  in transfer (:func:`pved.transfer.source_bank.source_steps`: the same moment where the
  pairs were aligned by physical time, else step t; the last row past the end of the
  source episode);
* δ: the theorem's hypothesis is KL ≤ δ for every pair, so δ is the largest per-pair KL
  between the shared Gaussian posteriors seen (a supremum estimated from below by a
  finite sample). A quantile of the KL (default 0.95) is reported beside it as a reading
  of typical pairs, with its own right-hand side, which is *not* the theorem's bound;
* vacuous: both rewards lie in [a − m, b + m], so their means differ by at most
  (b − a) + m whatever δ; the bound says more than that only when √(2δ) < 2 (δ < 2);
* [a, b]: the observed range of the source's per-step reward (its env's reward, the
  full Push reward for Reacher3);
* m: max over matched pairs of |r_T − r_S|, with the target evaluated under the same
  full reward (``target_env_kwargs={"reward": "full"}``). Caveat: R'_T and R'_S are only
  defined through the (assumed injective) decoders, so they cannot be evaluated at one
  and the same c; matched pairs have different c, so this m also absorbs part of what the
  δ term accounts for, and a max over a finite sample can under- or over-state the
  supremum over C.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from pved.diagnostics.rollouts import EpisodeRecord, model_inputs, run_paired_episodes
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.rl.policy import Policy
from pved.transfer.source_bank import source_steps


def theorem1_rhs(delta: float, a: float, b: float, m: float) -> float:
    """Right-hand side of Eq. 13: m + (b − a)/2 · √(2δ)."""
    if delta < 0 or m < 0 or b < a:
        raise PvedError(f"need delta >= 0, m >= 0 and a <= b, got {delta}, {m}, [{a}, {b}]")
    return float(m + (b - a) / 2.0 * math.sqrt(2.0 * delta))


def corollary1_rhs(
    delta: float, a: float, b: float, m: float, gamma: float, horizon: int | None = None
) -> float:
    """Right-hand side of Eq. 14 (``horizon`` None: the infinite-horizon 1/(1−γ) factor)
    or of Eq. 26 for steps t = 0..horizon−1 (factor Σ γ^t)."""
    if not 0.0 <= gamma <= 1.0:
        raise PvedError(f"gamma must be in [0, 1], got {gamma}")
    if horizon is None:
        if gamma >= 1.0:
            return math.inf
        factor = 1.0 / (1.0 - gamma)
    else:
        factor = float(np.sum(gamma ** np.arange(horizon)))
    return factor * theorem1_rhs(delta, a, b, m)


def gaussian_kl(
    mean_p: torch.Tensor, logvar_p: torch.Tensor, mean_q: torch.Tensor, logvar_q: torch.Tensor
) -> torch.Tensor:
    """Row-wise KL(p || q) between diagonal Gaussians, summed over dimensions."""
    var_p, var_q = logvar_p.exp(), logvar_q.exp()
    kl = 0.5 * (logvar_q - logvar_p + (var_p + (mean_p - mean_q) ** 2) / var_q - 1.0)
    return kl.sum(dim=-1)


def discounted_return(rewards: np.ndarray, gamma: float) -> float:
    return float(np.sum(rewards * gamma ** np.arange(len(rewards))))


@dataclass
class BoundResult:
    """Theorem 1 / Corollary 1 estimates beside the measured gaps (see module doc)."""

    delta: float  # the largest per-pair KL: Theorem 1's δ
    quantile: float
    delta_quantile: float  # the ``quantile`` of the per-pair KL (typical pairs; not δ)
    bound_quantile: float  # Eq. 13's right-hand side with ``delta_quantile`` (not a bound)
    vacuous: bool  # √(2δ) ≥ 2: the bound is no tighter than (b − a) + m
    kl_max: float
    kl_mean: float
    a: float
    b: float
    m: float
    bound: float  # Eq. 13
    mean_reward_source: float
    mean_reward_target: float
    gap: float  # |mean r_T − mean r_S|
    held: bool
    gamma: float
    horizon: int  # longest episode, the n of Eq. 26
    return_bound: float  # Eq. 14 (1/(1−γ))
    return_bound_finite: float  # Eq. 26 (Σ_{t<horizon} γ^t)
    mean_return_source: float
    mean_return_target: float
    return_gap: float
    return_held: bool
    matched_pairs: int
    episodes: int
    success_rate_source: float
    success_rate_target: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        return (
            f"Theorem 1: delta=max KL={self.delta:.4g} (q{self.quantile:g} "
            f"{self.delta_quantile:.4g}, mean {self.kl_mean:.4g}), "
            f"[a,b]=[{self.a:.4g},{self.b:.4g}], m={self.m:.4g} -> bound {self.bound:.4g}"
            f"{' (vacuous: sqrt(2 delta) >= 2)' if self.vacuous else ''} vs "
            f"gap {self.gap:.4g} ({'held' if self.held else 'VIOLATED'}); "
            f"with the q{self.quantile:g} KL in place of delta {self.bound_quantile:.4g} "
            "(typical pairs, not the theorem's bound); "
            f"Corollary 1 (gamma={self.gamma}): bound {self.return_bound:.4g} "
            f"(finite n={self.horizon}: {self.return_bound_finite:.4g}) vs return gap "
            f"{self.return_gap:.4g} ({'held' if self.return_held else 'VIOLATED'})"
        )


def match_steps(
    source: EpisodeRecord, target: EpisodeRecord, time_scale: float = 1.0
) -> np.ndarray:
    """Source step index for each target step, as the source bank's lookup in transfer
    gives it: round(t·time_scale), the last source row past its end."""
    t = np.arange(target.length)
    return source_steps(t, np.full(len(t), source.length), time_scale)


def estimate_bound(
    kl: np.ndarray,
    r_source_matched: np.ndarray,
    r_target_matched: np.ndarray,
    source_episode_rewards: Sequence[np.ndarray],
    target_episode_rewards: Sequence[np.ndarray],
    *,
    quantile: float = 0.95,
    gamma: float = 0.99,
    success_source: float = math.nan,
    success_target: float = math.nan,
) -> BoundResult:
    """Theorem 1 / Corollary 1 from per-pair KLs and rewards (see module doc for the
    estimators). ``*_episode_rewards`` are the per-step rewards of each episode."""
    if not 0.0 <= quantile <= 1.0:
        raise PvedError(f"quantile must be in [0, 1], got {quantile}")
    kl = np.asarray(kl, dtype=np.float64)
    r_s_all = np.concatenate(source_episode_rewards)
    r_t_all = np.concatenate(target_episode_rewards)
    # Theorem 1 assumes KL ≤ δ for every pair: its δ is the supremum, read as the max
    delta = max(float(kl.max()), 0.0)
    delta_q = float(np.quantile(kl, quantile))
    a, b = float(r_s_all.min()), float(r_s_all.max())
    m = float(np.max(np.abs(np.asarray(r_target_matched) - np.asarray(r_source_matched))))
    bound = theorem1_rhs(delta, a, b, m)
    gap = abs(float(r_t_all.mean()) - float(r_s_all.mean()))
    horizon = max(len(r) for r in (*source_episode_rewards, *target_episode_rewards))
    ret_s = float(np.mean([discounted_return(r, gamma) for r in source_episode_rewards]))
    ret_t = float(np.mean([discounted_return(r, gamma) for r in target_episode_rewards]))
    ret_bound = corollary1_rhs(delta, a, b, m, gamma)
    ret_bound_n = corollary1_rhs(delta, a, b, m, gamma, horizon)
    return_gap = abs(ret_t - ret_s)
    return BoundResult(
        delta=delta,
        quantile=quantile,
        delta_quantile=delta_q,
        bound_quantile=theorem1_rhs(max(delta_q, 0.0), a, b, m),
        vacuous=math.sqrt(2.0 * delta) >= 2.0,
        kl_max=float(kl.max()),
        kl_mean=float(kl.mean()),
        a=a,
        b=b,
        m=m,
        bound=bound,
        mean_reward_source=float(r_s_all.mean()),
        mean_reward_target=float(r_t_all.mean()),
        gap=gap,
        held=gap <= bound,
        gamma=gamma,
        horizon=int(horizon),
        return_bound=ret_bound,
        return_bound_finite=ret_bound_n,
        mean_return_source=ret_s,
        mean_return_target=ret_t,
        return_gap=return_gap,
        # The finite-horizon form is the one that applies to these finite episodes.
        return_held=return_gap <= ret_bound_n,
        matched_pairs=int(kl.shape[0]),
        episodes=len(source_episode_rewards),
        success_rate_source=success_source,
        success_rate_target=success_target,
    )


@torch.no_grad()
def theorem1_bound(
    model: SharedSpaceModel,
    source_policy: Policy,
    target_policy: Policy,
    source_env_id: str,
    target_env_id: str,
    episodes: int,
    seed: int,
    *,
    quantile: float = 0.95,
    gamma: float = 0.99,
    match_keys: Sequence[str] = (),
    source_env_kwargs: Mapping[str, Any] | None = None,
    target_env_kwargs: Mapping[str, Any] | None = None,
    max_steps: int | None = None,
    deterministic: bool = True,
    time_scale: float = 1.0,
) -> BoundResult:
    """Estimate Theorem 1 and Corollary 1 on rollouts of the source and the transferred
    target policy on the target task, and compare with the measured gaps.

    Args:
        model: the shared-space model used for transfer; needs Gaussian shared posteriors.
        source_env_kwargs: the source env's reward is its default (full for Reacher3).
        target_env_kwargs: default ``{"reward": "full"}``, so that R_T and R_S are the
            same reward terms and m compares like with like.
        time_scale: source steps per target step, as in transfer
            (:func:`pved.transfer.source_bank.bank_time_scale`).
        Others as :func:`pved.diagnostics.tsne.embed_rollouts`.
    """
    tgt_kwargs = {"reward": "full"} if target_env_kwargs is None else dict(target_env_kwargs)
    src, tgt, idx_s, idx_t = run_paired_episodes(
        source_policy,
        target_policy,
        source_env_id,
        target_env_id,
        episodes,
        seed,
        match_keys=match_keys,
        source_env_kwargs=source_env_kwargs,
        target_env_kwargs=tgt_kwargs,
        max_steps=max_steps,
        deterministic=deterministic,
    )
    model.eval()
    kls, r_s, r_t = [], [], []
    for ep_s, ep_t in zip(src, tgt, strict=True):
        j = match_steps(ep_s, ep_t, time_scale)
        q_s = model.shared_source(model_inputs(ep_s, idx_s)[j])
        q_t = model.shared_target(model_inputs(ep_t, idx_t))
        if q_s.logvar is None or q_t.logvar is None:
            raise PvedError(
                "Theorem 1 needs Gaussian shared posteriors; this model is deterministic"
            )
        # Direction as in Theorem 1: KL(q_φS(c|x_S) || q_φT(c|x_T)).
        kls.append(gaussian_kl(q_s.mean, q_s.logvar, q_t.mean, q_t.logvar).double().numpy())
        r_s.append(ep_s.reward[j])
        r_t.append(ep_t.reward)
    return estimate_bound(
        np.concatenate(kls),
        np.concatenate(r_s),
        np.concatenate(r_t),
        [e.reward for e in src],
        [e.reward for e in tgt],
        quantile=quantile,
        gamma=gamma,
        success_source=float(np.mean([e.success for e in src])),
        success_target=float(np.mean([e.success for e in tgt])),
    )
