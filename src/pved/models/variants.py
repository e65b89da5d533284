"""The four PVED ablations of paper IV.B ("Performance analysis and comparisons").

Each changes one component of PVED (``pved.models.pved``, Eqs. 2–10) "with the other
components fixed": same networks, same Eq. 9 weights (Table 1's α's apply through
:class:`PVEDConfig`), same training loop, same interface. Inputs are always full raw rows
``x_S = concat(s_S, a_S)`` (B, D_S) and ``x_T = concat(s_T, a_T)`` (B, D_T), so the
transfer stage needs no change.

- ``pved-state-only`` (:class:`PVEDStateOnly`): encoders and decoders see only the robot
  states s_S (the leading S_S entries of x_S) and s_T (S_T); the actions are sliced off.
- ``pved-shared-only`` (:class:`PVEDSharedOnly`): no individual subspace y; every decoder
  is fed c alone.
- ``pved-det-shared`` (:class:`PVEDDetShared`): c is a point (no sampling, no prior KL on
  c); y stays stochastic; L_C = −½‖c_S − c_T‖²; the shaping distance is ‖c_S − c_T‖.
- ``pved-vae`` (:class:`PVEDVAE`): each (c, y) decoder is fed the posterior inferred from
  its OWN agent's data (traditional VAE) instead of the other agent's.

The readings chosen where the paper is terse are in ``docs/decisions.md``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import nn

from pved.models.base import ModelDims, SharedRep, SharedSpaceModel
from pved.models.distributions import (
    DiagGaussian,
    gaussian_log_likelihood,
    kl_standard_normal,
    reparameterize,
)
from pved.models.pved import (
    PVED,
    PVEDConfig,
    check_same_batch,
    decoder_from_config,
    encoder_trunk,
    eq9_objective,
    to_diag_gaussian,
)

__all__ = [
    "PVEDVAE",
    "PVEDDetShared",
    "PVEDDetSharedConfig",
    "PVEDSharedOnly",
    "PVEDSharedOnlyConfig",
    "PVEDStateOnly",
    "PVEDStateOnlyConfig",
    "PVEDVAEConfig",
    "PointSharedEncoder",
]


# -- (1) state only ------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class PVEDStateOnlyConfig(PVEDConfig):
    """``pved-state-only``: PVED's settings unchanged (the ablation is structural)."""


class PVEDStateOnly(PVED):
    """PVED learned from the state distributions only (paper IV.B, variant 1).

    q_φS(c_T, y_T | s_S), q_φT(c_S, y_S | s_T), p_θT(s_T | c_T, y_T), p_θS(s_S | c_S, y_S),
    p_θ'T(s_S | c_T), p_θ'S(s_T | c_S): Eqs. 2–10 with every (s, a) replaced by s. The
    public methods still take full rows x (B, D) and slice the state (B, S) themselves;
    ``predict_*`` and ``reconstruct_*`` return states (B, S).
    """

    name = "pved-state-only"
    config_class = PVEDStateOnlyConfig
    states_only = True


# -- (2) shared subspace only ------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class PVEDSharedOnlyConfig(PVEDConfig):
    """``pved-shared-only``: PVED's settings with ``individual_dim`` fixed at 0.

    ``individual_dim`` is not an init argument, so a config built from a pair's PVED
    settings (``PairPreset.model_config``, which copies only init fields) cannot bring
    a y back, and setting one is an error rather than a silently ignored value.
    """

    individual_dim: int = dataclasses.field(default=0, init=False)


class PVEDSharedOnly(PVED):
    """PVED without the individual subspace (paper IV.B, variant 2).

    The encoders have no y head; p_θT(x_T | c_T) and p_θS(x_S | c_S) (Eqs. 2, 6) see c
    alone, like the Eq. 8 decoders. The Eq. 2 / Eq. 6 prior KL is then on c only.
    """

    name = "pved-shared-only"
    config_class = PVEDSharedOnlyConfig

    def spec(self) -> dict[str, Any]:
        """As :meth:`SharedSpaceModel.spec`, without config fields the class fixes
        (``individual_dim``): the saved config must rebuild through the config's
        ``__init__`` in :func:`pved.models.load_model`."""
        spec = super().spec()
        settable = {f.name for f in dataclasses.fields(self.config) if f.init}
        spec["config"] = {k: v for k, v in spec["config"].items() if k in settable}
        return spec


# -- (3) deterministic shared subspace ---------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class PVEDDetSharedConfig(PVEDConfig):
    """``pved-det-shared``: PVED's settings; ``alpha3`` weighs L_C = −½‖c_S − c_T‖²."""


class PointSharedEncoder(nn.Module):
    """PVED's encoder with a point-valued shared head: PVED's trunk, then a head giving c
    directly and, when Y > 0, PVED's Gaussian head for y.

    (B, D) -> (c of shape (B, C), DiagGaussian over y (B, Y) or None).
    """

    def __init__(self, in_dim: int, shared_dim: int, individual_dim: int, hidden: int):
        super().__init__()
        self.trunk = encoder_trunk(in_dim, hidden)
        self.head_c = nn.Linear(hidden, shared_dim)
        self.head_y = nn.Linear(hidden, 2 * individual_dim) if individual_dim > 0 else None

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, DiagGaussian | None]:
        h = self.trunk(x)
        q_y = to_diag_gaussian(self.head_y(h)) if self.head_y is not None else None
        return self.head_c(h), q_y

    def shared(self, x: torch.Tensor) -> torch.Tensor:
        """Only c (skips the y head): (B, D) -> (B, C)."""
        return self.head_c(self.trunk(x))


class PVEDDetShared(SharedSpaceModel):
    """PVED with a deterministic shared subspace (paper IV.B, variant 3).

    ``encoder_S`` maps x_S to a point c_T = f_S(x_S) and to q_φS(y_T | x_S);
    ``encoder_T`` maps x_T to c_S = f_T(x_T) and q_φT(y_S | x_T). The decoders and their
    wiring are PVED's. Eq. 9 with (per row; parts are batch means)::

        L_ST = E_{q_φS(y_T|x_S)}[log p_θT(x_T | c_T, y_T)] − KL(q_φS(y_T|x_S) ‖ N(0,I))  (Eq. 2)
        L_TS = E_{q_φT(y_S|x_T)}[log p_θS(x_S | c_S, y_S)] − KL(q_φT(y_S|x_T) ‖ N(0,I))  (Eq. 6)
        L_SS = log p_θ'T(x_S | c_T),   L_TT = log p_θ'S(x_T | c_S)                      (Eq. 8)
        L_C  = −½ ‖c_T − c_S‖²                                                          (Eq. 7)

    ½‖·‖² is Eq. 7's KL between unit-variance Gaussians centred on the two points, so α3
    keeps its Table-1 scale. Shaping (Eq. 10 with the paper's "Euclidean distance"):
    ‖c_T − c_S‖, shape (B,).
    """

    name = "pved-det-shared"
    config_class = PVEDDetSharedConfig
    config: PVEDDetSharedConfig

    def __init__(self, dims: ModelDims, config: PVEDDetSharedConfig | None = None):
        super().__init__(dims, config if config is not None else self.config_class())
        cfg = self.config
        c_dim, y_dim, hid = cfg.shared_dim, cfg.individual_dim, cfg.hidden
        self.encoder_S = PointSharedEncoder(dims.source_dim, c_dim, y_dim, hid)
        self.encoder_T = PointSharedEncoder(dims.target_dim, c_dim, y_dim, hid)
        self.decoder_T = decoder_from_config(cfg, y_dim, dims.target_dim)
        self.decoder_S = decoder_from_config(cfg, y_dim, dims.source_dim)
        self.decoder_T_prime = decoder_from_config(cfg, 0, dims.source_dim)
        self.decoder_S_prime = decoder_from_config(cfg, 0, dims.target_dim)

    def shared_source(self, x_S: torch.Tensor) -> SharedRep:
        """c_T = f_S(x_S) as (point (B, C), None)."""
        return SharedRep(self.encoder_S.shared(self.standardize_source(x_S)), None)

    def shared_target(self, x_T: torch.Tensor) -> SharedRep:
        """c_S = f_T(x_T) as (point (B, C), None)."""
        return SharedRep(self.encoder_T.shared(self.standardize_target(x_T)), None)

    def individual_source(self, x_S: torch.Tensor) -> SharedRep | None:
        """q_φS(y_T | x_S) as (mean, logvar), each (B, Y); None when Y = 0."""
        q_y = self.encoder_S(self.standardize_source(x_S))[1]
        return None if q_y is None else SharedRep(q_y.mean, q_y.logvar)

    def individual_target(self, x_T: torch.Tensor) -> SharedRep | None:
        """q_φT(y_S | x_T) as (mean, logvar), each (B, Y); None when Y = 0."""
        q_y = self.encoder_T(self.standardize_target(x_T))[1]
        return None if q_y is None else SharedRep(q_y.mean, q_y.logvar)

    def shaping(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """‖f_S(x_S) − f_T(x_T)‖, the Euclidean distance that replaces Eq. 10's KL: (B,)."""
        c_T = self.shared_source(x_S).mean
        c_S = self.shared_target(x_T).mean
        check_same_batch(c_T, c_S)
        return torch.linalg.vector_norm(c_T - c_S, dim=-1)

    def loss(
        self, x_S: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Eq. 9 (class docstring) on raw x_S (B, D_S), x_T (B, D_T).

        Returns batch means: ``L_ST, L_TS, L_SS, L_TT, L_C`` (to maximise), ``loglik_XY``
        for the four reconstruction terms, ``kl_ST``/``kl_TS`` (KLs of y only: c has no
        prior term), ``sqdist_C`` = ‖c_T − c_S‖² (so L_C = −½ sqdist_C), and ``total`` = −L
        to MINIMISE.
        """
        xs = self.standardize_source(x_S)
        xt = self.standardize_target(x_T)
        check_same_batch(xs, xt)
        c_T, q_y_T = self.encoder_S(xs)  # f_S(x_S), q_φS(y_T | x_S)
        c_S, q_y_S = self.encoder_T(xt)  # f_T(x_T), q_φT(y_S | x_T)
        y_T = None if q_y_T is None else reparameterize(q_y_T.mean, q_y_T.logvar, generator)
        y_S = None if q_y_S is None else reparameterize(q_y_S.mean, q_y_S.logvar, generator)
        zero = xs.new_zeros(xs.shape[0])
        kl_y_T = kl_standard_normal(*q_y_T) if q_y_T is not None else zero
        kl_y_S = kl_standard_normal(*q_y_S) if q_y_S is not None else zero

        ll_ST = gaussian_log_likelihood(xt, self.decoder_T(c_T, y_T), self.decoder_T.logvar)
        ll_TS = gaussian_log_likelihood(xs, self.decoder_S(c_S, y_S), self.decoder_S.logvar)
        ll_SS = gaussian_log_likelihood(xs, self.decoder_T_prime(c_T), self.decoder_T_prime.logvar)
        ll_TT = gaussian_log_likelihood(xt, self.decoder_S_prime(c_S), self.decoder_S_prime.logvar)
        sqdist = (c_T - c_S).pow(2).sum(dim=-1)

        parts = {
            "loglik_ST": ll_ST.mean(),
            "kl_ST": kl_y_T.mean(),
            "loglik_TS": ll_TS.mean(),
            "kl_TS": kl_y_S.mean(),
            "loglik_SS": ll_SS.mean(),
            "loglik_TT": ll_TT.mean(),
            "sqdist_C": sqdist.mean(),
        }
        parts["L_ST"] = parts["loglik_ST"] - parts["kl_ST"]
        parts["L_TS"] = parts["loglik_TS"] - parts["kl_TS"]
        parts["L_SS"] = parts["loglik_SS"]
        parts["L_TT"] = parts["loglik_TT"]
        parts["L_C"] = -0.5 * parts["sqdist_C"]
        parts["total"] = -eq9_objective(self.config, parts, self.warmup_epochs_done)
        return parts


# -- (4) traditional VAE posteriors ---------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class PVEDVAEConfig(PVEDConfig):
    """``pved-vae``: PVED's settings unchanged (the ablation is in the wiring)."""


class PVEDVAE(PVED):
    """PVED with traditional VAE posterior approximations (paper IV.B, variant 4).

    Each agent's latents are inferred from its OWN data: ``encoder_S`` is q_φS(c_S, y_S | x_S)
    and ``encoder_T`` is q_φT(c_T, y_T | x_T). Networks and parts are PVED's; only the
    inputs of the two (c, y) decoders change (per row; parts are batch means)::

        L_ST = E_{q_φT(c_T,y_T|x_T)}[log p_θT(x_T|c_T,y_T)] − KL(q_φT(c_T,y_T|x_T) ‖ N(0,I))
        L_TS = E_{q_φS(c_S,y_S|x_S)}[log p_θS(x_S|c_S,y_S)] − KL(q_φS(c_S,y_S|x_S) ‖ N(0,I))
        L_SS = E_{q_φS(c_S|x_S)}[log p(x_S | c_S)] − KL(q_φS(c_S|x_S) ‖ N(0,I))  (decoder_T_prime)
        L_TT = E_{q_φT(c_T|x_T)}[log p(x_T | c_T)] − KL(q_φT(c_T|x_T) ‖ N(0,I))  (decoder_S_prime)
        L_C  = −KL(q_φS(c_S|x_S) ‖ q_φT(c_T|x_T))

    Eqs. 2 and 6 become the plain VAE bound of Eq. 1 for each agent; Eq. 8 (already an
    own-data c-only VAE in PVED) is the same computation. The consistency term and the
    shaping keep PVED's form, the posterior inferred from x_S first:
    ``shaping = KL(q_φS(c_S|x_S) ‖ q_φT(c_T|x_T))`` (B,), usable at transfer time.
    """

    name = "pved-vae"
    config_class = PVEDVAEConfig
    crossed_posteriors = False

    @torch.no_grad()
    def predict_target(self, x_S: torch.Tensor) -> torch.Tensor:
        """Raw x_T predicted from x_S through the shared subspace: p_θT's mean at the mean
        of q_φS(c_S | x_S) and y_T at its prior mean 0 (nothing in x_S infers y_T):
        (B, D_S) -> (B, D_T)."""
        q_c, q_y = self.encode_source(x_S)
        y = None if q_y is None else torch.zeros_like(q_y.mean)
        return self.features_to_raw_target(self.decoder_T(q_c.mean, y))

    @torch.no_grad()
    def predict_source(self, x_T: torch.Tensor) -> torch.Tensor:
        """Raw x_S predicted from x_T, as :meth:`predict_target` the other way:
        (B, D_T) -> (B, D_S)."""
        q_c, q_y = self.encode_target(x_T)
        y = None if q_y is None else torch.zeros_like(q_y.mean)
        return self.features_to_raw_source(self.decoder_S(q_c.mean, y))
