"""Diagonal Gaussians: the closed forms every model's loss and shaping rests on.

All functions work on batches: a distribution is a pair ``(mean, logvar)`` of tensors of
shape ``(B, K)``; results reduce over the last dim and keep the batch, ``(B,)``.
Log-variances rather than variances are carried so that the networks' outputs need no
positivity constraint and the KL stays finite in float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

LOG_2PI = math.log(2.0 * math.pi)


class DiagGaussian(NamedTuple):
    """A batch of diagonal Gaussians: ``mean`` and ``logvar`` of shape (B, K)."""

    mean: torch.Tensor
    logvar: torch.Tensor


def kl_diag_gaussians(
    mean_q: torch.Tensor, logvar_q: torch.Tensor, mean_p: torch.Tensor, logvar_p: torch.Tensor
) -> torch.Tensor:
    """KL(q ‖ p) between diagonal Gaussians in closed form, summed over the last dim.

    Shapes: all (B, K) (or broadcastable); result (B,). This is the consistency term of
    Eq. 7 and the shaping distance of Eq. 10::

        KL = ½ Σ_k [ logvar_p − logvar_q + (var_q + (mean_q − mean_p)²) / var_p − 1 ]
    """
    var_ratio = torch.exp(logvar_q - logvar_p)
    mahalanobis = (mean_q - mean_p).pow(2) * torch.exp(-logvar_p)
    return 0.5 * (var_ratio + mahalanobis - 1.0 - (logvar_q - logvar_p)).sum(dim=-1)


def kl_standard_normal(mean: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mean, exp(logvar)) ‖ N(0, I)), summed over the last dim: (B, K) -> (B,).

    The prior terms of Eqs. 2, 6 and 8 (standard normal priors, paper III.G).
    """
    return 0.5 * (torch.exp(logvar) + mean.pow(2) - 1.0 - logvar).sum(dim=-1)


def reparameterize(
    mean: torch.Tensor, logvar: torch.Tensor, generator: torch.Generator | None = None
) -> torch.Tensor:
    """One sample per row, ``mean + exp(logvar / 2) · ε`` with ε ~ N(0, I): (B, K) -> (B, K).

    The reparameterisation trick (Kingma & Welling 2014) keeps the sample differentiable in
    ``mean`` and ``logvar``. ``generator`` makes the noise reproducible (validation).
    """
    eps = torch.randn(mean.shape, dtype=mean.dtype, device=mean.device, generator=generator)
    return mean + torch.exp(0.5 * logvar) * eps


def gaussian_log_likelihood(
    x: torch.Tensor, mean: torch.Tensor, logvar: torch.Tensor
) -> torch.Tensor:
    """log N(x | mean, diag(exp(logvar))) summed over the last dim: (B, D) -> (B,).

    ``logvar`` may be (B, D) or (D,) (one learned variance per output dim).
    """
    return -0.5 * ((x - mean).pow(2) * torch.exp(-logvar) + logvar + LOG_2PI).sum(dim=-1)


def soft_clamp(x: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """Smoothly keep ``x`` within [low, high]: identity well inside, flat near the bounds.

    Used on log-variances so that an encoder can never emit a variance whose KL overflows
    float32 (an unbounded shaping reward would wreck PPO), while gradients never vanish
    abruptly the way they do under a hard clamp.
    """
    x = low + F.softplus(x - low)
    return high - F.softplus(high - x)
