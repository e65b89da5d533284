"""PPO's pure functions: generalised advantage estimation and the clipped loss.

No state and no env: arrays in, arrays out, so each is checked against a hand computation
or against the other (``ppo_loss`` in torch, ``ppo_loss_grad`` in numpy with its gradient
in closed form; tests/test_ppo.py). :func:`pved.rl.ppo.train_ppo` composes them.

Conventions. T = ``steps_per_env``, N = ``num_envs``, B = a minibatch, A = action dim.
"""

from __future__ import annotations

import numpy as np
import torch

from pved.errors import PvedError
from pved.rl.networks import LOG_2PI

# ========================================================================================
# 1. Generalised advantage estimation
# ========================================================================================


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    dones: np.ndarray,
    next_values: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """GAE(γ, λ) advantages and λ-returns over a rollout.

    ``δ_t = r_t + γ·V'_t − V(s_t)``, ``A_t = δ_t + γλ·(1 − done_t)·A_{t+1}``, where
    ``V'_t`` is the value of the state that *followed* step t in its own episode: V of the
    next observation, V of ``final_obs`` when the episode was truncated at t, and 0 when it
    terminated at t. Passing next values explicitly is what makes truncated episodes
    bootstrap correctly under same-step autoreset.

    Args:
        rewards: (T, N).
        values: (T, N) V(s_t).
        dones: (T, N) bool, the episode ended at step t (terminated or truncated): the
            λ-recursion does not cross into the next episode.
        next_values: (T, N) V'_t as above (0 where terminated).
        gamma, gae_lambda: γ and λ.

    Returns:
        advantages (T, N) and returns = advantages + values (T, N), float64.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    next_values = np.asarray(next_values, dtype=np.float64)
    if not (rewards.shape == values.shape == next_values.shape == np.shape(dones)):
        raise PvedError(
            f"compute_gae needs equal (T, N) shapes, got rewards {rewards.shape}, values "
            f"{values.shape}, dones {np.shape(dones)}, next_values {next_values.shape}"
        )
    continues = 1.0 - np.asarray(dones, dtype=np.float64)
    deltas = rewards + gamma * next_values - values
    advantages = np.zeros_like(rewards)
    last = np.zeros(rewards.shape[1:], dtype=np.float64)
    for t in range(rewards.shape[0] - 1, -1, -1):
        last = deltas[t] + gamma * gae_lambda * continues[t] * last
        advantages[t] = last
    return advantages, advantages + values


# ========================================================================================
# 2. The PPO loss
# ========================================================================================


def gaussian_log_prob_np(actions: np.ndarray, mean: np.ndarray, log_std: np.ndarray) -> np.ndarray:
    """log N(actions; mean, diag(exp(log_std))²): actions, mean (B, A); log_std (A,) → (B,)."""
    diff = actions - mean
    inv_var = np.exp(-2.0 * log_std)
    out: np.ndarray = -0.5 * ((diff * diff) @ inv_var) - (
        log_std.sum() + 0.5 * mean.shape[1] * LOG_2PI
    )
    return out


def ppo_loss(
    mean: torch.Tensor,
    log_std: torch.Tensor,
    values: torch.Tensor,
    actions: torch.Tensor,
    old_log_prob: torch.Tensor,
    advantages: torch.Tensor,
    returns: torch.Tensor,
    old_values: torch.Tensor,
    *,
    clip: float,
    clip_value: float | None,
    ent_coef: float,
    vf_coef: float,
    normalize_advantage: bool = True,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PPO's loss on one minibatch (differentiable).

    ``L = −mean(min(ρ·Â, clip(ρ, 1−ε, 1+ε)·Â)) + vf_coef·½·mean((V − R)²) − ent_coef·H``
    with ``ρ = π(a|s)/π_old(a|s)``, Â the (optionally standardised) advantages, and H the
    Gaussian's entropy. With ``clip_value``, the value term is
    ``½·mean(max((V − R)², (V_old + clip(V − V_old, ±clip_value) − R)²))``.

    Args:
        mean: (B, A) action means under the current parameters.
        log_std: (A,) current log standard deviation.
        values: (B,) current V(s).
        actions: (B, A) the (unclipped) actions taken.
        old_log_prob: (B,) their log-probability when taken.
        advantages: (B,) GAE advantages.
        returns: (B,) λ-returns (value targets).
        old_values: (B,) V(s) when the rollout was collected.

    Returns:
        (scalar loss, stats) with stats ``policy_loss``, ``value_loss``, ``entropy``,
        ``approx_kl`` (the k3 estimator E[(ρ − 1) − log ρ]) and ``clip_fraction``
        (detached scalars).
    """
    act_dim = mean.shape[1]
    diff = actions - mean
    log_prob = -0.5 * (diff * diff * torch.exp(-2.0 * log_std)).sum(dim=1) - (
        log_std.sum() + 0.5 * act_dim * LOG_2PI
    )
    log_ratio = log_prob - old_log_prob
    ratio = torch.exp(log_ratio)
    if normalize_advantage and advantages.shape[0] > 1:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    surrogate = torch.min(advantages * ratio, advantages * ratio.clamp(1.0 - clip, 1.0 + clip))
    policy_loss = -surrogate.mean()
    sq = (values - returns) ** 2
    if clip_value is not None:
        clipped = old_values + (values - old_values).clamp(-clip_value, clip_value)
        sq = torch.max(sq, (clipped - returns) ** 2)
    value_loss = 0.5 * sq.mean()
    entropy = log_std.sum() + 0.5 * act_dim * (1.0 + LOG_2PI)
    loss = policy_loss + vf_coef * value_loss - ent_coef * entropy
    with torch.no_grad():
        stats = {
            "policy_loss": policy_loss.detach(),
            "value_loss": value_loss.detach(),
            "entropy": entropy.detach(),
            "approx_kl": ((ratio - 1.0) - log_ratio).mean(),
            "clip_fraction": ((ratio - 1.0).abs() > clip).float().mean(),
        }
    return loss, stats


def ppo_loss_grad(
    mean: np.ndarray,
    log_std: np.ndarray,
    values: np.ndarray,
    actions: np.ndarray,
    old_log_prob: np.ndarray,
    advantages: np.ndarray,
    returns: np.ndarray,
    old_values: np.ndarray,
    *,
    clip: float,
    clip_value: float | None,
    ent_coef: float,
    vf_coef: float,
    normalize_advantage: bool = True,
) -> tuple[dict[str, float], np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ppo_loss` and its gradient in closed form (numpy, float32 in and out).

    Same arguments and shapes as :func:`ppo_loss`. The derivative of the clipped
    surrogate w.r.t. log π is ``−Â·ρ/B`` where the unclipped term is the minimum (ties
    included) and 0 where clipping is active; chained through the Gaussian log-density
    this gives ``dL/dmean = g·(a − μ)/σ²`` and ``dL/dlog_std = Σ_b g·((a − μ)²/σ² − 1)``.

    Returns:
        (stats as floats, incl. ``loss``; dL/dmean (B, A); dL/dlog_std (A,);
        dL/dvalues (B,)).
    """
    batch, act_dim = mean.shape
    diff = actions - mean
    inv_var = np.exp(-2.0 * log_std)
    z2 = diff * diff
    log_prob = -0.5 * (z2 @ inv_var) - (log_std.sum() + 0.5 * act_dim * LOG_2PI)
    log_ratio = log_prob - old_log_prob
    ratio = np.exp(log_ratio)
    if normalize_advantage and batch > 1:
        advantages = (advantages - advantages.mean()) / (advantages.std(ddof=1) + 1e-8)
    surr1 = advantages * ratio
    surr2 = advantages * np.clip(ratio, 1.0 - clip, 1.0 + clip)
    unclipped = surr1 <= surr2
    policy_loss = -float(np.where(unclipped, surr1, surr2).mean())
    # policy gradient through log π
    g = (surr1 * unclipped) * np.float32(-1.0 / batch)
    d_mean = (g[:, None] * diff) * inv_var
    d_log_std = (g @ (z2 * inv_var)) - g.sum() - np.float32(ent_coef)
    # value loss
    err = values - returns
    if clip_value is None:
        value_loss = 0.5 * float(np.dot(err, err)) / batch
        d_values = err * np.float32(vf_coef / batch)
    else:
        delta = values - old_values
        clipped_err = old_values + np.clip(delta, -clip_value, clip_value) - returns
        sq, sq_c = err * err, clipped_err * clipped_err
        use_plain = sq >= sq_c
        value_loss = 0.5 * float(np.where(use_plain, sq, sq_c).mean())
        inside = np.abs(delta) <= clip_value
        d_values = np.where(use_plain, err, clipped_err * inside) * np.float32(vf_coef / batch)
    entropy = float(log_std.sum()) + 0.5 * act_dim * (1.0 + LOG_2PI)
    stats = {
        "loss": policy_loss + vf_coef * value_loss - ent_coef * entropy,
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": entropy,
        "approx_kl": float(((ratio - 1.0) - log_ratio).mean()),
        "clip_fraction": float((np.abs(ratio - 1.0) > clip).mean()),
    }
    return (
        stats,
        d_mean.astype(np.float32, copy=False),
        d_log_std.astype(np.float32, copy=False),
        d_values.astype(np.float32, copy=False),
    )


__all__ = ["compute_gae", "gaussian_log_prob_np", "ppo_loss", "ppo_loss_grad"]
