"""Eq. 10's distance to a PVED's target code, and its gradient with respect to the
target's raw input, in numpy: what ``pved-align``'s guide computes at every PPO
minibatch (:class:`pved.transfer.align_guide.AlignGuide`).

Why by hand: the guide is D(q_φS(c | x_S), q_φT(c | x_T)) through the frozen target
encoder, forward and backward to x_T, on minibatches of 64 rows. At that size torch's
per-operator dispatch and its autograd engine cost more than the arithmetic: about 1 ms
a minibatch on reacher, as much as PPO's own gradient (the ratios are in
docs/results.md, "What the shaping costs a run"). The same reason, and the same encoder
code, as the models' training step (:mod:`pved.models.numpy_grad`); in numpy a pass
costs about a quarter of autograd's.

Covered: :class:`pved.models.pved.PVED` and its variants that keep its target encoder,
features and KL (:func:`numpy_distance_covers`); any other model keeps autograd. The
values and gradients are checked against autograd in ``tests/test_align.py``; only
floating-point rounding differs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pved.models.base import SharedSpaceModel
from pved.models.numpy_grad import _Encoder, _EncoderCache, _kl_diag, _linear, _Views
from pved.models.pved import ENCODER_LOGVAR_BOUNDS, PVED

__all__ = ["TargetDistance", "numpy_distance_covers"]


def numpy_distance_covers(model: SharedSpaceModel) -> bool:
    """True when :class:`TargetDistance` computes ``model``'s ``shaping_between(q_S,
    shared_target(x_T))``: a PVED (or a variant) with a Gaussian shared code that does not
    override how its target code is formed or how the distance is taken."""
    if not isinstance(model, PVED):
        return False
    cls = type(model)
    return (
        cls.shared_target is PVED.shared_target
        and cls.features_target is PVED.features_target
        and cls.shaping_between is SharedSpaceModel.shaping_between
    )


def _softplus_sigmoid(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """softplus(z) and σ(z) from one exponential, z (B, K) float32; above 20 softplus is
    z itself (torch's own threshold), where e^z would also overflow soon."""
    e = np.exp(np.minimum(z, np.float32(20.0)))
    softplus = np.log1p(e)
    np.copyto(softplus, z, where=z > 20.0)
    return softplus, e / (np.float32(1.0) + e)


def _soft_clamp(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pved.models.distributions.soft_clamp` of a raw log-variance (B, K) to
    :data:`ENCODER_LOGVAR_BOUNDS` and its slope: the training step's
    (``numpy_grad._gaussian_head``) in half the operators, two exponentials shared by the
    softplus and sigmoid of each bound. It differs from that one in the last float32
    bits, which is why training keeps its own: the models' bits stay as published."""
    low, high = (np.float32(b) for b in ENCODER_LOGVAR_BOUNDS)
    softplus_low, sigmoid_low = _softplus_sigmoid(raw - low)
    inner = low + softplus_low
    softplus_high, sigmoid_high = _softplus_sigmoid(high - inner)
    return high - softplus_high, sigmoid_low * sigmoid_high


@dataclass
class _Pass:
    """What one forward pass keeps for the backward one."""

    encoder: _EncoderCache
    diff: np.ndarray  # (B, C) mean_S − mean_T
    inv_var_T: np.ndarray  # (B, C) e^−logvar_T
    ratio: np.ndarray  # (B, C) e^(logvar_S − logvar_T)


class TargetDistance:
    """KL(q_φS(c | x_S) ‖ q_φT(c | x_T)) (Eq. 10) from the source's code and the target's
    raw x_T, through ``model``'s target encoder, which it reads in place (a frozen model:
    its weights are numpy views of the module's).

    Args:
        model: a model for which :func:`numpy_distance_covers` holds.
    """

    def __init__(self, model: SharedSpaceModel) -> None:
        if not numpy_distance_covers(model):
            raise ValueError(f"model {model.name!r} forms its distance its own way")
        assert isinstance(model, PVED)
        named = list(model.encoder_T.named_parameters())
        params = [p.detach().numpy() for _, p in named]
        # the encoder's backward writes no parameter gradients here (params=False);
        # buffers of their shapes keep its views complete
        views = _Views(
            [f"encoder_T.{name}" for name, _ in named], params, [np.zeros_like(p) for p in params]
        )
        self.encoder = _Encoder(views, "encoder_T", point_c=False)
        # the standardisation folded into the first layer, which then reads raw x_T's
        # first W entries: (x − m)/s · Wᵀ + b = x · (W/s)ᵀ + (b − W·(m/s)); two operators
        # fewer each way (a frozen model's: read once, here)
        norm = model.target_norm
        self.width = model.target_width
        self.dim = int(norm.mean.shape[0])
        mean = norm.mean.detach().numpy()[: self.width].astype(np.float64)
        std = norm.std.detach().numpy()[: self.width].astype(np.float64)
        weight, bias = (a.astype(np.float64) for a in self.encoder.l1)
        self.encoder.l1 = (
            np.ascontiguousarray(weight / std, dtype=np.float32),
            (bias - weight @ (mean / std)).astype(np.float32),
        )

    def forward(
        self, mean_S: np.ndarray, logvar_S: np.ndarray, x_T: np.ndarray
    ) -> tuple[np.ndarray, _Pass]:
        """D per row and what :meth:`input_grad` needs.

        Args:
            mean_S, logvar_S: (B, C) float32, the source's posterior q_φS(c | x_S).
            x_T: (B, D_T) float32, the target's raw state-action rows.

        Returns:
            (D (B,) float32, the pass).
        """
        enc = self._encode(x_T[:, : self.width])
        assert enc.logvar_c is not None
        diff = mean_S - enc.mean_c
        distance, inv_var_T, ratio = _kl_diag(diff, logvar_S, enc.logvar_c)
        return distance, _Pass(enc, diff, inv_var_T, ratio)

    def _encode(self, x: np.ndarray) -> _EncoderCache:
        """The encoder's c posterior for inputs x (B, W): ``_Encoder.forward`` with the
        soft clamp of :func:`_soft_clamp`."""
        e = self.encoder
        pre1 = _linear(x, e.l1)
        h1 = np.maximum(pre1, np.float32(0.0))
        pre2 = _linear(h1, e.l2)
        h2 = np.maximum(pre2, np.float32(0.0))
        out = _linear(h2, e.head_c)
        k = out.shape[1] // 2
        logvar, slope = _soft_clamp(out[:, k:])
        return _EncoderCache(x, pre1, h1, pre2, h2, out[:, :k], logvar, slope, None, None, None)

    def input_grad(self, done: _Pass, d_distance: np.ndarray) -> np.ndarray:
        """The gradient with respect to the raw x_T (B, D_T) of Σ_rows d_distance · D.

        Args:
            done: :meth:`forward`'s pass.
            d_distance: (B,) float32, dLoss/dD per row.
        """
        d = d_distance[:, None]
        pull = done.diff * done.inv_var_T  # −dD/dmean_T
        d_mean = pull * -d
        d_logvar = (1.0 - done.ratio - pull * done.diff) * (np.float32(0.5) * d)
        d_seen = self.encoder.backward(done.encoder, d_mean, d_logvar, None, None, params=False)
        assert d_seen is not None
        if self.width == self.dim:
            return d_seen
        d_x = np.zeros((d_seen.shape[0], self.dim), dtype=np.float32)
        d_x[:, : self.width] = d_seen  # the entries the encoder does not see
        return d_x
