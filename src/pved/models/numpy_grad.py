"""The shared-space models' training losses and their gradients written out in numpy.

:func:`pved.models.train_model` trains every registered model through a
:class:`NumpyStep` by default: :class:`PVEDNumpyStep` for Eq. 9 (``pved``,
``pved-state-only``, ``pved-shared-only``, ``pved-vae``, whose loss is :meth:`PVED.loss`,
and ``pved-det-shared``'s :meth:`PVEDDetShared.loss`) and :class:`GuptaNumpyStep` for
``gupta2017``. Each computes the same objective as the model's ``loss``, with the same
reparameterisation noise (drawn from torch's global generator in the same order and
shapes), and applies torch.optim.Adam's update to the same parameter memory; only
floating-point rounding differs. ``backend="torch"`` trains with autograd instead, as
does any model subclass with a loss of its own.

Why by hand: a PVED step at batch 256 is ~150 small operators (four encoder heads, four
decoders, five Gaussian terms) forward and as many backward, and at these sizes torch's
per-operator dispatch and autograd bookkeeping cost more than the arithmetic. The
measured ratios are in docs/results.md ("Model training speed"); the losses and
gradients are checked against autograd in ``tests/test_models_pved.py``.

Notation as in :mod:`pved.models.pved`. Shapes: B rows; W_S, W_T the widths the networks
see; C = ``shared_dim``, Y = ``individual_dim``, H = ``hidden``. Names ending ``_S`` are
inferred from x_S (q_φS(c_T, y_T | x_S)), ``_T`` from x_T. A torch ``nn.Linear`` weight
is (out, in) and computes ``x @ W.T + b``; the numpy code uses the same views.

One module past 600 lines on purpose: it is the forward and backward pass of one
objective (Eq. 9, and Gupta's), whose caches pass from a layer's forward to its
backward; split, a layer's two halves would live apart.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pved.errors import PvedError
from pved.flat import FlatAdam, FlatParams, clip_grad_norm_np
from pved.models.base import SharedSpaceModel
from pved.models.distributions import LOG_2PI
from pved.models.gupta import Gupta2017, Gupta2017Config, weighted_total
from pved.models.pved import (
    ENCODER_LOGVAR_BOUNDS,
    OBJECTIVE_TERMS,
    PVED,
    PVEDConfig,
    consistency_scale,
    eq9_objective,
)
from pved.models.variants import PVEDDetShared

__all__ = [
    "DET_SHARED_PART_NAMES",
    "GUPTA_PART_NAMES",
    "PART_NAMES",
    "GuptaNumpyStep",
    "NumpyStep",
    "PVEDNumpyStep",
    "numpy_step",
    "numpy_trainable",
]

#: The loss parts :meth:`PVEDNumpyStep.step` returns for PVED, its variants with
#: Gaussian c, in :meth:`PVED.loss`'s order.
PART_NAMES = (
    *(f"{piece}_{term}" for term in ("ST", "TS", "SS", "TT") for piece in ("loglik", "kl")),
    *OBJECTIVE_TERMS,
    "total",
)
#: The same for ``pved-det-shared``, in :meth:`PVEDDetShared.loss`'s order: no prior
#: KL on the point c, and the squared distance behind its L_C.
DET_SHARED_PART_NAMES = (
    *("loglik_ST", "kl_ST", "loglik_TS", "kl_TS", "loglik_SS", "loglik_TT", "sqdist_C"),
    *OBJECTIVE_TERMS,
    "total",
)
#: The same for ``gupta2017``, in :meth:`Gupta2017.loss`'s order.
GUPTA_PART_NAMES = ("recon_S", "recon_T", "align", "total")

Linear = tuple[np.ndarray, np.ndarray]  # (W (out, in), b (out,))

#: torch.optim.Adam's default epsilon, which model training uses.
ADAM_EPS = 1e-8


def numpy_trainable(model: SharedSpaceModel) -> bool:
    """True when ``model``'s training loss is one this module computes: PVED's own
    (:meth:`PVED.loss` and :meth:`PVED.objective`, which its state-only, shared-only and
    VAE variants inherit), :meth:`PVEDDetShared.loss` or :meth:`Gupta2017.loss`. A
    subclass that overrides them keeps autograd."""
    if isinstance(model, PVED):
        pved_class = type(model)
        return pved_class.loss is PVED.loss and pved_class.objective is PVED.objective
    if isinstance(model, PVEDDetShared):
        return type(model).loss is PVEDDetShared.loss
    return isinstance(model, Gupta2017) and type(model).loss is Gupta2017.loss


def numpy_step(model: SharedSpaceModel, lr: float, grad_clip: float | None) -> NumpyStep:
    """The :class:`NumpyStep` that trains ``model`` (see :func:`numpy_trainable`)."""
    if isinstance(model, Gupta2017):
        return GuptaNumpyStep(model, lr, grad_clip)
    return PVEDNumpyStep(model, lr, grad_clip)


def _sigmoid(z: np.ndarray) -> np.ndarray:
    """Logistic function without overflow for any float32 input."""
    return np.float32(0.5) * (np.float32(1.0) + np.tanh(np.float32(0.5) * z))


def _softplus(z: np.ndarray) -> np.ndarray:
    """log(1 + e^z), stable for large |z| (torch's softplus up to its z > 20 shortcut,
    where the two differ by less than float32 resolves)."""
    return np.logaddexp(np.float32(0.0), z)


def _linear(x: np.ndarray, layer: Linear) -> np.ndarray:
    out = x @ layer[0].T
    out += layer[1]
    return out


def _linear_backward(x: np.ndarray, d_out: np.ndarray, grad: Linear) -> None:
    """Write dW = d_outᵀ x and db = Σ_rows d_out into ``grad``'s buffers."""
    np.matmul(d_out.T, x, out=grad[0])
    # as a product with a row of ones: BLAS sums the rows at about twice np.sum's speed
    np.matmul(np.ones(d_out.shape[0], dtype=np.float32), d_out, out=grad[1])


class _Views:
    """A model's parameters and their gradient buffers as numpy views, by parameter name;
    remembers which were taken, so that a parameter the numpy step does not use is an
    error rather than a weight that silently never trains."""

    def __init__(self, names: list[str], params: list[np.ndarray], grads: list[np.ndarray]):
        self.views = dict(zip(names, zip(params, grads, strict=True), strict=True))
        self.taken: set[str] = set()

    def has(self, name: str) -> bool:
        return name in self.views

    def take(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        self.taken.add(name)
        return self.views[name]

    def linear(self, prefix: str) -> tuple[Linear, Linear]:
        """((W, b), (dW, db)) of the ``nn.Linear`` at ``prefix``."""
        (w, gw), (b, gb) = self.take(f"{prefix}.weight"), self.take(f"{prefix}.bias")
        return (w, b), (gw, gb)

    def untaken(self) -> list[str]:
        return sorted(set(self.views) - self.taken)


@dataclass
class _EncoderCache:
    x: np.ndarray  # (B, W) the input
    pre1: np.ndarray  # (B, H) first trunk layer before ReLU
    h1: np.ndarray
    pre2: np.ndarray  # (B, H) second trunk layer before ReLU
    h2: np.ndarray
    mean_c: np.ndarray  # (B, C): the posterior's mean, or the point c of pved-det-shared
    logvar_c: np.ndarray | None  # None for a point
    dclamp_c: np.ndarray | None  # d logvar / d raw head output (soft clamp's slope)
    mean_y: np.ndarray | None  # (B, Y)
    logvar_y: np.ndarray | None
    dclamp_y: np.ndarray | None


@dataclass
class _DecoderCache:
    c: np.ndarray  # (B, C)
    y: np.ndarray | None  # (B, Y)
    slope0: np.ndarray  # (B, H or 2H) leaky ReLU's slope after the first layers
    a0: np.ndarray  # their output
    slope1: np.ndarray  # (B, H) the same after the second layer
    a1: np.ndarray
    mean: np.ndarray  # (B, W) the likelihood's mean


class _Encoder:
    """Views of a :class:`pved.models.pved.GaussianEncoder`'s parameters and gradients,
    or (``point_c``) of a :class:`pved.models.variants.PointSharedEncoder`'s."""

    def __init__(self, views: _Views, prefix: str, point_c: bool) -> None:
        self.point_c = point_c
        (self.l1, self.g1), (self.l2, self.g2) = (
            views.linear(f"{prefix}.trunk.0"),
            views.linear(f"{prefix}.trunk.2"),
        )
        self.head_c, self.g_head_c = views.linear(f"{prefix}.head_c")
        self.head_y: Linear | None = None
        self.g_head_y: Linear | None = None
        if views.has(f"{prefix}.head_y.weight"):
            self.head_y, self.g_head_y = views.linear(f"{prefix}.head_y")

    def forward(self, x: np.ndarray) -> _EncoderCache:
        pre1 = _linear(x, self.l1)
        h1 = np.maximum(pre1, np.float32(0.0))
        pre2 = _linear(h1, self.l2)
        h2 = np.maximum(pre2, np.float32(0.0))
        if self.point_c:
            mean_c, logvar_c, dclamp_c = _linear(h2, self.head_c), None, None
        else:
            mean_c, logvar_c, dclamp_c = _gaussian_head(h2, self.head_c)
        mean_y = logvar_y = dclamp_y = None
        if self.head_y is not None:
            mean_y, logvar_y, dclamp_y = _gaussian_head(h2, self.head_y)
        return _EncoderCache(
            x, pre1, h1, pre2, h2, mean_c, logvar_c, dclamp_c, mean_y, logvar_y, dclamp_y
        )

    def backward(
        self,
        cache: _EncoderCache,
        d_mean_c: np.ndarray,
        d_logvar_c: np.ndarray | None,
        d_mean_y: np.ndarray | None,
        d_logvar_y: np.ndarray | None,
        params: bool = True,
    ) -> np.ndarray | None:
        """Write the parameters' gradients (unless ``params`` is False) from those of the
        posteriors' parts; with ``params`` False, return the gradient with respect to the
        input x (B, W) instead (the y head is then not used: pass None for it)."""
        d_out_c = d_mean_c
        if d_logvar_c is not None:
            assert cache.dclamp_c is not None
            d_out_c = np.concatenate([d_mean_c, d_logvar_c * cache.dclamp_c], axis=1)
        if params:
            _linear_backward(cache.h2, d_out_c, self.g_head_c)
        d_h2 = d_out_c @ self.head_c[0]
        if self.head_y is not None and d_mean_y is not None:
            assert self.g_head_y is not None and cache.dclamp_y is not None
            assert d_logvar_y is not None and params
            d_out_y = np.concatenate([d_mean_y, d_logvar_y * cache.dclamp_y], axis=1)
            _linear_backward(cache.h2, d_out_y, self.g_head_y)
            d_h2 += d_out_y @ self.head_y[0]
        d_h2 *= cache.pre2 > 0.0  # torch's ReLU passes no gradient at exactly 0
        if params:
            _linear_backward(cache.h1, d_h2, self.g2)
        d_h1 = d_h2 @ self.l2[0]
        d_h1 *= cache.pre1 > 0.0
        if params:
            _linear_backward(cache.x, d_h1, self.g1)
            return None
        return d_h1 @ self.l1[0]


def _gaussian_head(h: np.ndarray, head: Linear) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pved.models.pved.to_diag_gaussian` of ``head(h)``: (mean, logvar, slope of
    the soft clamp), each (B, K). The clamp is ``high − softplus(high − (low +
    softplus(raw − low)))``, whose slope is σ(raw − low) · σ(high − inner)."""
    out = _linear(h, head)
    k = out.shape[1] // 2
    mean, raw = out[:, :k], out[:, k:]
    low, high = (np.float32(b) for b in ENCODER_LOGVAR_BOUNDS)
    inner = low + _softplus(raw - low)
    logvar = high - _softplus(high - inner)
    slope = _sigmoid(raw - low) * _sigmoid(high - inner)
    return mean, logvar, slope


class _Decoder:
    """Views of a :class:`pved.models.pved.Decoder`'s parameters and gradients."""

    def __init__(self, views: _Views, prefix: str, cfg: PVEDConfig) -> None:
        self.from_c, self.g_from_c = views.linear(f"{prefix}.from_c")
        self.from_y: Linear | None = None
        self.g_from_y: Linear | None = None
        if views.has(f"{prefix}.from_y.weight"):
            self.from_y, self.g_from_y = views.linear(f"{prefix}.from_y")
        (self.l1, self.g1), (self.l2, self.g2) = (
            views.linear(f"{prefix}.body.0"),
            views.linear(f"{prefix}.body.2"),
        )
        self.raw_logvar: np.ndarray | None = None
        self.g_raw_logvar: np.ndarray | None = None
        if views.has(f"{prefix}.raw_logvar"):
            self.raw_logvar, self.g_raw_logvar = views.take(f"{prefix}.raw_logvar")
        self.hidden = self.from_c[0].shape[0]
        self.slope = np.float32(cfg.leaky_slope)
        self.min_logvar = np.float32(2.0 * math.log(cfg.min_decoder_std))

    def _leaky(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Leaky ReLU of z and its slope at z (1 where z > 0, else ``leaky_slope``, as
        torch's backward takes it); max(z, slope·z) holds for 0 <= slope <= 1."""
        positive = (z > 0.0).astype(np.float32)
        if 0.0 <= self.slope <= 1.0:
            return np.maximum(z, z * self.slope), np.maximum(positive, self.slope)
        slope = positive + (1.0 - positive) * self.slope
        return z * slope, slope

    def forward(self, c: np.ndarray, y: np.ndarray | None) -> _DecoderCache:
        pre0 = _linear(c, self.from_c)
        if self.from_y is not None:
            if y is None:
                raise PvedError("this decoder needs the individual factors y")
            pre0 = np.concatenate([pre0, _linear(y, self.from_y)], axis=1)
        a0, slope0 = self._leaky(pre0)
        a1, slope1 = self._leaky(_linear(a0, self.l1))
        return _DecoderCache(c, y, slope0, a0, slope1, a1, _linear(a1, self.l2))

    def logvar(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(D,) log-variance and its slope in ``raw_logvar`` (None for unit variance)."""
        if self.raw_logvar is None:
            return np.zeros(self.l2[0].shape[0], dtype=np.float32), None
        shifted = self.raw_logvar - self.min_logvar
        return self.min_logvar + _softplus(shifted), _sigmoid(shifted)

    def backward(
        self, cache: _DecoderCache, d_mean: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Gradients of the decoder's weights from d(loss)/d(mean) (B, W); returns the
        gradients with respect to its inputs c (B, C) and y (B, Y) or None."""
        _linear_backward(cache.a1, d_mean, self.g2)
        d_a1 = d_mean @ self.l2[0]
        d_a1 *= cache.slope1
        _linear_backward(cache.a0, d_a1, self.g1)
        d_a0 = d_a1 @ self.l1[0]
        d_a0 *= cache.slope0
        d_hc = d_a0[:, : self.hidden]
        _linear_backward(cache.c, d_hc, self.g_from_c)
        d_c = d_hc @ self.from_c[0]
        d_y = None
        if self.from_y is not None:
            assert self.g_from_y is not None and cache.y is not None
            d_hy = d_a0[:, self.hidden :]
            _linear_backward(cache.y, d_hy, self.g_from_y)
            d_y = d_hy @ self.from_y[0]
        return d_c, d_y


def _log_likelihood(
    x: np.ndarray, decoder: _Decoder, cache: _DecoderCache, coef: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of log N(x | mean, diag(e^logvar)) (B,), and d(coef · Σ rows)/d mean (B, W);
    the gradient of the decoder's log-variance is written to its buffer."""
    logvar, dlogvar_draw = decoder.logvar()
    inv_var = np.exp(-logvar)
    resid = x - cache.mean
    weighted = resid * inv_var
    sq = resid * weighted
    rows = np.float32(-0.5) * (sq + logvar + np.float32(LOG_2PI)).sum(axis=1)
    if decoder.g_raw_logvar is not None:
        assert dlogvar_draw is not None
        d_logvar = np.float32(coef) * (np.float32(0.5) * sq.sum(axis=0) - 0.5 * x.shape[0])
        decoder.g_raw_logvar[...] = d_logvar * dlogvar_draw
    return rows, np.float32(coef) * weighted


def _kl_standard_normal(mean: np.ndarray, logvar: np.ndarray) -> np.ndarray:
    """KL(N(mean, e^logvar) ‖ N(0, I)) per row, (B, K) -> (B,)."""
    return np.float32(0.5) * (np.exp(logvar) + mean * mean - 1.0 - logvar).sum(axis=1)


def _kl_diag(
    diff: np.ndarray, logvar_S: np.ndarray, logvar_T: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KL(q_S ‖ q_T) between diagonal Gaussians per row (Eqs. 7 and 10), from diff =
    mean_S − mean_T and the two log-variances, all (B, K); returns (KL (B,), e^−logvar_T,
    e^(logvar_S − logvar_T)), the last two what its gradients are made of:
    dKL/dmean_T = −diff·e^−logvar_T, dKL/dlogvar_T = ½(1 − ratio − diff²·e^−logvar_T)."""
    inv_var_T = np.exp(-logvar_T)
    ratio = np.exp(logvar_S - logvar_T)
    kl = np.float32(0.5) * (ratio + diff * diff * inv_var_T - 1.0 - (logvar_S - logvar_T)).sum(
        axis=1
    )
    return kl, inv_var_T, ratio


class NumpyStep(abc.ABC):
    """One Adam step of a model's training loss on a minibatch, the loss and its gradient
    computed in numpy by a subclass.

    Construction re-homes ``model``'s parameters into one flat buffer
    (:class:`pved.flat.FlatParams`); the module keeps working as an ordinary torch module
    on the same memory (validation, checkpoints, shaping).

    Args:
        model: a model for which :func:`numpy_trainable` holds.
        lr: Adam's learning rate; ``eps`` and the betas are torch.optim.Adam's defaults.
        grad_clip: global gradient-norm bound, or None.
    """

    #: The names of the parts :meth:`loss_and_grad` returns, in the model's ``loss`` order.
    part_names: tuple[str, ...]

    def __init__(self, model: SharedSpaceModel, lr: float, grad_clip: float | None) -> None:
        if not numpy_trainable(model):
            raise PvedError(f"model {model.name!r} has its own loss; train it with autograd")
        self.model = model
        self.lr = float(lr)
        self.grad_clip = grad_clip
        names = [name for name, _ in model.named_parameters()]
        # model.parameters() order, the order of a torch Adam's state over the model
        self.params = [p for _, p in model.named_parameters()]
        self.flat = FlatParams(self.params)
        self.adam = FlatAdam(self.flat.flat_np.size, eps=ADAM_EPS)
        views = _Views(names, self.flat.params_np, self.flat.grads_np)
        self._bind(views)
        if views.untaken():
            raise PvedError(
                f"model {model.name!r} has parameters the numpy step does not train: "
                f"{', '.join(views.untaken())}"
            )

    @abc.abstractmethod
    def _bind(self, views: _Views) -> None:
        """Take the numpy views of every parameter the loss uses."""

    @abc.abstractmethod
    def features(self, x_S: torch.Tensor, x_T: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """Raw rows (N, D_S), (N, D_T) -> the standardised entries the networks see, as
        contiguous float32 arrays ((N, W_S), (N, W_T)), ready for :meth:`step`."""

    @abc.abstractmethod
    def loss_and_grad(self, xs: np.ndarray, xt: np.ndarray, epochs_done: float) -> np.ndarray:
        """The loss parts on features xs (B, W_S), xt (B, W_T) in :attr:`part_names`
        order (batch means, ``total`` last, to minimise), and d total / d parameters
        written to ``self.flat.grad_np``."""

    def step(self, xs: np.ndarray, xt: np.ndarray, epochs_done: float) -> np.ndarray:
        """:meth:`loss_and_grad`, then (when the loss is finite) gradient clipping and one
        Adam step on the parameters; returns the parts. A non-finite loss leaves the
        parameters untouched."""
        parts = self.loss_and_grad(xs, xt, epochs_done)
        if np.isfinite(parts[-1]):
            if self.grad_clip is not None:
                clip_grad_norm_np(self.flat.grad_np, self.grad_clip)
            self.adam.step(self.flat.flat_np, self.flat.grad_np, self.lr)
        return parts

    # -- torch.optim.Adam's state dict, so checkpoints do not depend on the backend --------
    def save_to(self, optimizer: torch.optim.Adam) -> None:
        """Put the Adam moments and step count into ``optimizer`` (a torch Adam over
        ``model.parameters()``), whose ``state_dict()`` then goes into the checkpoint."""
        for p, where in zip(self.params, self.flat.slices, strict=True):
            if self.adam.t == 0:
                optimizer.state.pop(p, None)
                continue
            optimizer.state[p] = {
                "step": torch.tensor(float(self.adam.t)),
                "exp_avg": torch.from_numpy(self.adam.m[where].reshape(p.shape).copy()),
                "exp_avg_sq": torch.from_numpy(self.adam.v[where].reshape(p.shape).copy()),
            }

    def load_from(self, optimizer: torch.optim.Adam) -> None:
        """Take the Adam moments and step count from ``optimizer`` (e.g. just loaded
        from a checkpoint written by either backend)."""
        steps = set()
        for p, where in zip(self.params, self.flat.slices, strict=True):
            state: dict[str, Any] = optimizer.state.get(p, {})
            if not state:
                self.adam.m[where] = 0.0
                self.adam.v[where] = 0.0
                steps.add(0)
                continue
            self.adam.m[where] = state["exp_avg"].detach().reshape(-1).numpy()
            self.adam.v[where] = state["exp_avg_sq"].detach().reshape(-1).numpy()
            steps.add(int(float(state["step"])))
        if len(steps) > 1:
            raise PvedError(f"optimizer state has parameters at different steps {sorted(steps)}")
        self.adam.t = steps.pop() if steps else 0


class PVEDNumpyStep(NumpyStep):
    """Eq. 9 (PVED and its four variants): forward and backward in numpy."""

    def _bind(self, views: _Views) -> None:
        model = self.model
        assert isinstance(model.config, PVEDConfig)
        self.cfg: PVEDConfig = model.config
        #: pved-det-shared: c is a point, L_C = −½‖c_S − c_T‖² (pved.models.variants).
        self.point_shared = isinstance(model, PVEDDetShared)
        #: Eqs. 2 and 6 take the other agent's posterior (False: pved-vae's own).
        self.crossed = bool(getattr(model, "crossed_posteriors", True))
        self.part_names = DET_SHARED_PART_NAMES if self.point_shared else PART_NAMES
        self.encoder_S = _Encoder(views, "encoder_S", self.point_shared)
        self.encoder_T = _Encoder(views, "encoder_T", self.point_shared)
        self.decoder_T = _Decoder(views, "decoder_T", self.cfg)
        self.decoder_S = _Decoder(views, "decoder_S", self.cfg)
        self.decoder_T_prime = _Decoder(views, "decoder_T_prime", self.cfg)
        self.decoder_S_prime = _Decoder(views, "decoder_S_prime", self.cfg)

    @torch.no_grad()
    def features(self, x_S: torch.Tensor, x_T: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        model = self.model
        if isinstance(model, PVED):
            fs, ft = model.features_source(x_S), model.features_target(x_T)
        else:
            fs, ft = model.standardize_source(x_S), model.standardize_target(x_T)
        return np.ascontiguousarray(fs.numpy()), np.ascontiguousarray(ft.numpy())

    # -- the objective and its gradient ----------------------------------------------------
    def loss_and_grad(self, xs: np.ndarray, xt: np.ndarray, epochs_done: float) -> np.ndarray:
        """Eq. 9's parts (``total`` = −L, α3 scaled by the warm-up at ``epochs_done``)
        and their gradient, as :meth:`NumpyStep.loss_and_grad`."""
        cfg, point = self.cfg, self.point_shared
        batch = xs.shape[0]
        if xt.shape[0] != batch:
            raise PvedError(f"source and target batches differ in size: {batch} vs {xt.shape[0]}")
        self.flat.grad_np.fill(0.0)
        enc_S = self.encoder_S.forward(xs)
        enc_T = self.encoder_T.forward(xt)
        # The noise the model's loss draws from torch's generator, in its order: c from
        # x_S, c from x_T (not for a point c), then y from x_S, y from x_T.
        c_S, c_T = enc_S.mean_c, enc_T.mean_c
        eps_c_S = eps_c_T = std_c_S = std_c_T = None
        if not point:
            assert enc_S.logvar_c is not None and enc_T.logvar_c is not None
            eps_c_S = torch.randn(c_S.shape).numpy()
            eps_c_T = torch.randn(c_T.shape).numpy()
            std_c_S, std_c_T = np.exp(0.5 * enc_S.logvar_c), np.exp(0.5 * enc_T.logvar_c)
            c_S = c_S + std_c_S * eps_c_S
            c_T = c_T + std_c_T * eps_c_T
        y_S = y_T = None
        eps_y_S = eps_y_T = std_y_S = std_y_T = None
        if enc_S.mean_y is not None and enc_T.mean_y is not None:
            assert enc_S.logvar_y is not None and enc_T.logvar_y is not None
            eps_y_S = torch.randn(enc_S.mean_y.shape).numpy()
            eps_y_T = torch.randn(enc_T.mean_y.shape).numpy()
            std_y_S, std_y_T = np.exp(0.5 * enc_S.logvar_y), np.exp(0.5 * enc_T.logvar_y)
            y_S = enc_S.mean_y + std_y_S * eps_y_S
            y_T = enc_T.mean_y + std_y_T * eps_y_T

        zeros = np.zeros(batch, dtype=np.float32)
        kl_c_S = kl_c_T = kl_y_S = kl_y_T = zeros  # a point c has no prior term
        if enc_S.logvar_c is not None and enc_T.logvar_c is not None:
            kl_c_S = _kl_standard_normal(enc_S.mean_c, enc_S.logvar_c)
            kl_c_T = _kl_standard_normal(enc_T.mean_c, enc_T.logvar_c)
        if enc_S.mean_y is not None and enc_S.logvar_y is not None:
            kl_y_S = _kl_standard_normal(enc_S.mean_y, enc_S.logvar_y)
        if enc_T.mean_y is not None and enc_T.logvar_y is not None:
            kl_y_T = _kl_standard_normal(enc_T.mean_y, enc_T.logvar_y)

        # Coefficients of each per-row term in total = −L, L a batch mean (Eq. 9).
        a1, a2 = cfg.alpha1 / batch, cfg.alpha2 / batch
        a3 = consistency_scale(cfg, epochs_done) * cfg.alpha3 / batch

        # Eqs. 2 and 6: crossed (PVED) or own (pved-vae) posteriors into p_θT and p_θS.
        crossed = self.crossed
        c_in_T, y_in_T = (c_S, y_S) if crossed else (c_T, y_T)
        c_in_S, y_in_S = (c_T, y_T) if crossed else (c_S, y_S)
        dec_T = self.decoder_T.forward(c_in_T, y_in_T)
        dec_S = self.decoder_S.forward(c_in_S, y_in_S)
        dec_Tp = self.decoder_T_prime.forward(c_S, None)
        dec_Sp = self.decoder_S_prime.forward(c_T, None)
        ll_ST, d_mean_T = _log_likelihood(xt, self.decoder_T, dec_T, -a1)
        ll_TS, d_mean_S = _log_likelihood(xs, self.decoder_S, dec_S, -a1)
        ll_SS, d_mean_Tp = _log_likelihood(xs, self.decoder_T_prime, dec_Tp, -a2)
        ll_TT, d_mean_Sp = _log_likelihood(xt, self.decoder_S_prime, dec_Sp, -a2)
        # Eq. 7: KL(q(c|x_S) ‖ q(c|x_T)), or ½‖c_S − c_T‖² between points.
        diff = enc_S.mean_c - enc_T.mean_c
        if point:
            inv_var_T = ratio = np.ones_like(diff)
            sqdist = (diff * diff).sum(axis=1)
            kl_C = np.float32(0.5) * sqdist
        else:
            assert enc_S.logvar_c is not None and enc_T.logvar_c is not None
            kl_C, inv_var_T, ratio = _kl_diag(diff, enc_S.logvar_c, enc_T.logvar_c)

        # -- backward: decoders, then the samples, then the posteriors -------------------
        d_c_in_T, d_y_in_T = self.decoder_T.backward(dec_T, d_mean_T)
        d_c_in_S, d_y_in_S = self.decoder_S.backward(dec_S, d_mean_S)
        d_c_S, _ = self.decoder_T_prime.backward(dec_Tp, d_mean_Tp)
        d_c_T, _ = self.decoder_S_prime.backward(dec_Sp, d_mean_Sp)
        if crossed:
            d_c_S, d_c_T = d_c_S + d_c_in_T, d_c_T + d_c_in_S
            d_y_S, d_y_T = d_y_in_T, d_y_in_S
        else:
            d_c_S, d_c_T = d_c_S + d_c_in_S, d_c_T + d_c_in_T
            d_y_S, d_y_T = d_y_in_S, d_y_in_T

        # The consistency term's pull on the two means (points), d(a3·kl_C)/d mean.
        pull = np.float32(a3) * diff * inv_var_T
        d_mean_c_S = d_c_S + pull
        d_mean_c_T = d_c_T - pull
        d_logvar_c_S = d_logvar_c_T = None
        if not point:
            # c = mean + e^(logvar/2)·ε; each c's prior KL weighs α1 (Eq. 2 or 6) + α2
            # (Eq. 8).
            assert enc_S.logvar_c is not None and enc_T.logvar_c is not None
            kc = np.float32(a1 + a2)
            d_mean_c_S += kc * enc_S.mean_c
            d_mean_c_T += kc * enc_T.mean_c
            d_logvar_c_S = (
                d_c_S * eps_c_S * std_c_S * np.float32(0.5)
                + kc * np.float32(0.5) * (np.exp(enc_S.logvar_c) - 1.0)
                + np.float32(a3 * 0.5) * (ratio - 1.0)
            )
            d_logvar_c_T = (
                d_c_T * eps_c_T * std_c_T * np.float32(0.5)
                + kc * np.float32(0.5) * (np.exp(enc_T.logvar_c) - 1.0)
                + np.float32(a3 * 0.5) * (1.0 - ratio - diff * diff * inv_var_T)
            )
        d_mean_y_S = d_logvar_y_S = d_mean_y_T = d_logvar_y_T = None
        if y_S is not None:
            assert d_y_S is not None and d_y_T is not None and enc_T.mean_y is not None
            assert enc_S.mean_y is not None and enc_S.logvar_y is not None
            assert enc_T.logvar_y is not None
            ky = np.float32(a1)
            d_mean_y_S = d_y_S + ky * enc_S.mean_y
            d_mean_y_T = d_y_T + ky * enc_T.mean_y
            d_logvar_y_S = d_y_S * eps_y_S * std_y_S * np.float32(0.5) + ky * np.float32(0.5) * (
                np.exp(enc_S.logvar_y) - 1.0
            )
            d_logvar_y_T = d_y_T * eps_y_T * std_y_T * np.float32(0.5) + ky * np.float32(0.5) * (
                np.exp(enc_T.logvar_y) - 1.0
            )
        self.encoder_S.backward(enc_S, d_mean_c_S, d_logvar_c_S, d_mean_y_S, d_logvar_y_S)
        self.encoder_T.backward(enc_T, d_mean_c_T, d_logvar_c_T, d_mean_y_T, d_logvar_y_T)

        # -- the logged parts, as the model's loss names them ----------------------------
        kl_in_T = (kl_c_S + kl_y_S) if crossed else (kl_c_T + kl_y_T)
        kl_in_S = (kl_c_T + kl_y_T) if crossed else (kl_c_S + kl_y_S)
        means = {
            "loglik_ST": ll_ST.mean(dtype=np.float64),
            "kl_ST": kl_in_T.mean(dtype=np.float64),
            "loglik_TS": ll_TS.mean(dtype=np.float64),
            "kl_TS": kl_in_S.mean(dtype=np.float64),
            "loglik_SS": ll_SS.mean(dtype=np.float64),
            "kl_SS": kl_c_S.mean(dtype=np.float64),
            "loglik_TT": ll_TT.mean(dtype=np.float64),
            "kl_TT": kl_c_T.mean(dtype=np.float64),
            "sqdist_C": 2.0 * kl_C.mean(dtype=np.float64),
        }
        for term in ("ST", "TS", "SS", "TT"):
            means[f"L_{term}"] = means[f"loglik_{term}"] - means[f"kl_{term}"]
        means["L_C"] = -kl_C.mean(dtype=np.float64)
        means["total"] = -eq9_objective(cfg, means, epochs_done)
        return np.array([means[name] for name in self.part_names], dtype=np.float64)


class _ReluMLP:
    """Views of a three-layer ReLU MLP, ``nn.Sequential(encoder_trunk, nn.Linear)`` (the
    networks of :class:`Gupta2017`), with its forward and backward passes."""

    def __init__(self, views: _Views, prefix: str) -> None:
        self.layers = [
            views.linear(f"{prefix}.0.0"),
            views.linear(f"{prefix}.0.2"),
            views.linear(f"{prefix}.1"),
        ]

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """(B, in) -> (B, out) and the inputs of each layer (for :meth:`backward`)."""
        inputs = [x]
        h = x
        for k, (layer, _) in enumerate(self.layers):
            h = _linear(h, layer)
            if k < len(self.layers) - 1:
                np.maximum(h, np.float32(0.0), out=h)  # ReLU's output > 0 iff its input is
                inputs.append(h)
        return h, inputs

    def backward(self, inputs: list[np.ndarray], d_out: np.ndarray) -> np.ndarray:
        """Write the weights' gradients from d(loss)/d(output) (B, out); returns
        d(loss)/d(input) (B, in)."""
        delta = d_out
        for k in range(len(self.layers) - 1, -1, -1):
            (weight, _), grad = self.layers[k]
            _linear_backward(inputs[k], delta, grad)
            delta = delta @ weight
            if k > 0:
                delta *= inputs[k] > 0.0
        return delta


class GuptaNumpyStep(NumpyStep):
    """Gupta et al. 2017's loss (:class:`Gupta2017`): two autoencoders and the alignment
    of their embeddings, forward and backward in numpy. Deterministic: no noise."""

    part_names = GUPTA_PART_NAMES

    def _bind(self, views: _Views) -> None:
        assert isinstance(self.model.config, Gupta2017Config)
        self.cfg_gupta: Gupta2017Config = self.model.config
        self.embed_S = _ReluMLP(views, "embed_S")
        self.embed_T = _ReluMLP(views, "embed_T")
        self.decode_S = _ReluMLP(views, "decode_S")
        self.decode_T = _ReluMLP(views, "decode_T")

    @torch.no_grad()
    def features(self, x_S: torch.Tensor, x_T: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        model = self.model
        assert isinstance(model, Gupta2017)
        fs, ft = model.states_source(x_S), model.states_target(x_T)
        return np.ascontiguousarray(fs.numpy()), np.ascontiguousarray(ft.numpy())

    def loss_and_grad(self, xs: np.ndarray, xt: np.ndarray, epochs_done: float) -> np.ndarray:
        """recon_S, recon_T, align and their weighted sum (module docstring of
        :mod:`pved.models.gupta`); ``epochs_done`` is unused."""
        cfg = self.cfg_gupta
        batch = xs.shape[0]
        if xt.shape[0] != batch:
            raise PvedError(f"source and target batches differ in size: {batch} vs {xt.shape[0]}")
        self.flat.grad_np.fill(0.0)
        f, f_inputs = self.embed_S.forward(xs)
        g, g_inputs = self.embed_T.forward(xt)
        rec_S, rec_S_inputs = self.decode_S.forward(f)
        rec_T, rec_T_inputs = self.decode_T.forward(g)
        err_S, err_T, gap = rec_S - xs, rec_T - xt, f - g
        recon_S = (err_S * err_S).sum(axis=1)
        recon_T = (err_T * err_T).sum(axis=1)
        align = (gap * gap).sum(axis=1)
        # d(w · mean ‖e‖²)/d e = 2w e / B
        w_S = np.float32(2.0 * cfg.weight_recon_source / batch)
        w_T = np.float32(2.0 * cfg.weight_recon_target / batch)
        w_A = np.float32(2.0 * cfg.weight_align / batch)
        d_f = self.decode_S.backward(rec_S_inputs, w_S * err_S) + w_A * gap
        d_g = self.decode_T.backward(rec_T_inputs, w_T * err_T) - w_A * gap
        self.embed_S.backward(f_inputs, d_f)
        self.embed_T.backward(g_inputs, d_g)
        means = {
            "recon_S": float(recon_S.mean(dtype=np.float64)),
            "recon_T": float(recon_T.mean(dtype=np.float64)),
            "align": float(align.mean(dtype=np.float64)),
        }
        means["total"] = weighted_total(cfg, means)
        return np.array([means[name] for name in self.part_names], dtype=np.float64)
