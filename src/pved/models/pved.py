"""The paired variational encoder-decoder (PVED), paper section III.C (Eqs. 1–10) and III.G.

Notation (the paper's): source S, target T; ``x_S = concat(s_S, a_S)`` (B, D_S) and
``x_T = concat(s_T, a_T)`` (B, D_T); shared factors c, individual factors y.

Networks:

- ``encoder_S`` = q_φS(c_T, y_T | x_S) and ``encoder_T`` = q_φT(c_S, y_S | x_T): note the
  crossing — the SOURCE encoder infers the TARGET's factors (Eq. 2) and vice versa (Eq. 6).
- ``decoder_T`` = p_θT(x_T | c_T, y_T) and ``decoder_S`` = p_θS(x_S | c_S, y_S).
- ``decoder_T_prime`` = p_θ'T(x_S | c_T) and ``decoder_S_prime`` = p_θ'S(x_T | c_S): the
  c-only decoders of Eq. 8 that reconstruct each encoder's OWN input from its shared part.

Objective (Eq. 9), maximised::

    L = α1 (L_ST + L_TS) + α2 (L_SS + L_TT) + α3 L_C

    L_ST = E_{q_φS(c_T,y_T|x_S)}[log p_θT(x_T|c_T,y_T)] − KL(q_φS(c_T,y_T|x_S) ‖ N(0,I))   (Eq. 2)
    L_TS = E_{q_φT(c_S,y_S|x_T)}[log p_θS(x_S|c_S,y_S)] − KL(q_φT(c_S,y_S|x_T) ‖ N(0,I))   (Eq. 6)
    L_SS = E_{q_φS(c_T|x_S)}[log p_θ'T(x_S|c_T)] − KL(q_φS(c_T|x_S) ‖ N(0,I))              (Eq. 8)
    L_TT = E_{q_φT(c_S|x_T)}[log p_θ'S(x_T|c_S)] − KL(q_φT(c_S|x_T) ‖ N(0,I))              (Eq. 8)
    L_C  = − KL(q_φS(c_T|x_S) ‖ q_φT(c_S|x_T))                                              (Eq. 7)

Readings where the paper is terse (also in the report for ``docs/decisions.md``):

- "Three-layer networks of 64 units" = three linear layers, two hidden layers of 64: the
  encoder is D→64→64 then two heads 64→(2·10) for c and for y; the decoders map c→64 and
  y→64 separately, concatenate (128), then 128→64→D; the c-only decoders are 10→64→64→D.
- Decoder likelihood: a Gaussian on the standardised data with one learned log-variance per
  output dimension and decoder (``decoder_variance="learned"``, floored at std
  ``min_decoder_std``). With a fixed unit variance on unit-variance data the reconstruction
  term is too weak against the KL terms for the latents to carry much information (the
  probabilistic-PCA argument: only directions with variance above the noise variance get
  encoded); ``decoder_variance="unit"`` keeps that simpler choice available.
- One reparameterised sample per datum: the same sample of c_T feeds decoder_T (Eq. 2) and
  decoder_T_prime (Eq. 8), and likewise c_S; both expectations stay unbiased.
- Log-likelihoods and KLs are summed over dimensions and averaged over the batch.
- Encoder log-variances are softly bounded to [−12, 8] so that the KL of Eq. 10 can never
  overflow into the shaping reward.
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F
from torch import nn

from pved.errors import PvedError
from pved.models.base import ModelConfig, ModelDims, SharedRep, SharedSpaceModel
from pved.models.distributions import (
    DiagGaussian,
    gaussian_log_likelihood,
    kl_diag_gaussians,
    kl_standard_normal,
    reparameterize,
    soft_clamp,
)

DECODER_VARIANCES = ("learned", "unit")
ENCODER_LOGVAR_BOUNDS = (-12.0, 8.0)

#: The Eq. 9 terms, in the order they are logged.
OBJECTIVE_TERMS = ("L_ST", "L_TS", "L_SS", "L_TT", "L_C")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PVEDConfig(ModelConfig):
    """PVED hyperparameters (paper III.G, Table 1) plus the shared training settings.

    Attributes:
        alpha1: weight of the cross terms L_ST + L_TS (Eqs. 2, 6).
        alpha2: weight of the c-only terms L_SS + L_TT (Eq. 8).
        alpha3: weight of the consistency term L_C (Eq. 7).
        shared_dim: dimension of c (paper: 10).
        individual_dim: dimension of y (paper: 10; 0 removes the individual subspace).
        hidden: units per hidden layer (paper: 64).
        leaky_slope: negative slope of the decoders' leaky ReLU (torch's default).
        decoder_variance: "learned" (one log-variance per output dim) or "unit".
        min_decoder_std: floor of a learned decoder std, in standardised units.

    Defaults are the Reacher pair of Table 1 (α1=1, α2=1, α3=10), Adam lr 1e-4, batch 256.
    """

    alpha1: float = 1.0
    alpha2: float = 1.0
    alpha3: float = 10.0
    shared_dim: int = 10
    individual_dim: int = 10
    hidden: int = 64
    leaky_slope: float = 0.01
    decoder_variance: str = "learned"
    min_decoder_std: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("alpha1", "alpha2", "alpha3"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise PvedError(f"config: {name} must be a finite number >= 0, got {value}")
        if self.shared_dim < 1:
            raise PvedError(f"config: shared_dim must be >= 1, got {self.shared_dim}")
        if self.individual_dim < 0:
            raise PvedError(f"config: individual_dim must be >= 0, got {self.individual_dim}")
        if self.hidden < 1:
            raise PvedError(f"config: hidden must be >= 1, got {self.hidden}")
        if self.decoder_variance not in DECODER_VARIANCES:
            raise PvedError(
                f"config: decoder_variance must be one of {', '.join(DECODER_VARIANCES)}, "
                f"got {self.decoder_variance!r}"
            )
        if not self.min_decoder_std > 0:
            raise PvedError(f"config: min_decoder_std must be > 0, got {self.min_decoder_std}")


class GaussianEncoder(nn.Module):
    """q(c, y | x): a trunk shared by both subspaces, then one head per subspace.

    (B, D) -> (DiagGaussian over c of shape (B, C), DiagGaussian over y (B, Y) or None).
    ReLU activations (paper III.G).
    """

    def __init__(self, in_dim: int, shared_dim: int, individual_dim: int, hidden: int):
        super().__init__()
        self.trunk = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.head_c = nn.Linear(hidden, 2 * shared_dim)
        self.head_y = nn.Linear(hidden, 2 * individual_dim) if individual_dim > 0 else None

    @staticmethod
    def _split(out: torch.Tensor) -> DiagGaussian:
        mean, raw_logvar = out.chunk(2, dim=-1)
        return DiagGaussian(mean, soft_clamp(raw_logvar, *ENCODER_LOGVAR_BOUNDS))

    def forward(self, x: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        h = self.trunk(x)
        q_y = self._split(self.head_y(h)) if self.head_y is not None else None
        return self._split(self.head_c(h)), q_y

    def shared(self, x: torch.Tensor) -> DiagGaussian:
        """Only the c posterior (skips the y head): (B, D) -> (B, C)."""
        return self._split(self.head_c(self.trunk(x)))


class Decoder(nn.Module):
    """p(x | c, y) or, with ``individual_dim=0``, p(x | c): the mean of a diagonal Gaussian.

    c and y each get their own first layer (``hidden`` units each), the two are
    concatenated and go through two more layers (paper III.G); leaky ReLU. The variance is
    one learned log-variance per output dim (``logvar``), or 1.
    (B, C), (B, Y) -> mean (B, D).
    """

    def __init__(
        self,
        shared_dim: int,
        individual_dim: int,
        out_dim: int,
        hidden: int,
        leaky_slope: float,
        learned_variance: bool,
        min_std: float,
    ):
        super().__init__()
        self.from_c = nn.Linear(shared_dim, hidden)
        self.from_y = nn.Linear(individual_dim, hidden) if individual_dim > 0 else None
        width = 2 * hidden if self.from_y is not None else hidden
        self.body = nn.Sequential(
            nn.Linear(width, hidden), nn.LeakyReLU(leaky_slope), nn.Linear(hidden, out_dim)
        )
        self.leaky_slope = leaky_slope
        self.out_dim = out_dim
        self.min_logvar = 2.0 * math.log(min_std)
        self.raw_logvar = nn.Parameter(torch.zeros(out_dim)) if learned_variance else None

    def forward(self, c: torch.Tensor, y: torch.Tensor | None = None) -> torch.Tensor:
        h = self.from_c(c)
        if self.from_y is not None:
            if y is None:
                raise PvedError("this decoder needs the individual factors y")
            h = torch.cat([h, self.from_y(y)], dim=-1)
        return self.body(F.leaky_relu(h, self.leaky_slope))

    @property
    def logvar(self) -> torch.Tensor:
        """(D,) log-variance of the likelihood; a smooth floor keeps the density bounded on
        dims the decoder predicts exactly."""
        if self.raw_logvar is None:
            return torch.zeros(self.out_dim, device=self.from_c.weight.device)
        return self.min_logvar + F.softplus(self.raw_logvar - self.min_logvar)


class PVED(SharedSpaceModel):
    """The paired variational encoder-decoder (see the module docstring for Eqs. 2–10)."""

    name = "pved"
    config_class = PVEDConfig
    config: PVEDConfig

    def __init__(self, dims: ModelDims, config: PVEDConfig | None = None):
        super().__init__(dims, config if config is not None else PVEDConfig())
        cfg = self.config
        c_dim, y_dim, hid = cfg.shared_dim, cfg.individual_dim, cfg.hidden
        learned = cfg.decoder_variance == "learned"

        def decoder(individual_dim: int, out_dim: int) -> Decoder:
            return Decoder(
                c_dim, individual_dim, out_dim, hid, cfg.leaky_slope, learned, cfg.min_decoder_std
            )

        # q_φS(c_T, y_T | s_S, a_S) and q_φT(c_S, y_S | s_T, a_T)
        self.encoder_S = GaussianEncoder(dims.source_dim, c_dim, y_dim, hid)
        self.encoder_T = GaussianEncoder(dims.target_dim, c_dim, y_dim, hid)
        # p_θT(s_T, a_T | c_T, y_T) (Eq. 2) and p_θS(s_S, a_S | c_S, y_S) (Eq. 6)
        self.decoder_T = decoder(y_dim, dims.target_dim)
        self.decoder_S = decoder(y_dim, dims.source_dim)
        # p_θ'T(s_S, a_S | c_T) and p_θ'S(s_T, a_T | c_S) (Eq. 8)
        self.decoder_T_prime = decoder(0, dims.source_dim)
        self.decoder_S_prime = decoder(0, dims.target_dim)

    # -- posteriors ----------------------------------------------------------------------
    def encode_source(self, x_S: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        """q_φS(c_T, y_T | x_S) from raw x_S (B, D_S): ((B, C), (B, Y) or None)."""
        return self.encoder_S(self.standardize_source(x_S))

    def encode_target(self, x_T: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        """q_φT(c_S, y_S | x_T) from raw x_T (B, D_T): ((B, C), (B, Y) or None)."""
        return self.encoder_T(self.standardize_target(x_T))

    def shared_source(self, x_S: torch.Tensor) -> SharedRep:
        """q_φS(c_T | x_S) as (mean, logvar), each (B, C)."""
        q = self.encoder_S.shared(self.standardize_source(x_S))
        return SharedRep(q.mean, q.logvar)

    def shared_target(self, x_T: torch.Tensor) -> SharedRep:
        """q_φT(c_S | x_T) as (mean, logvar), each (B, C)."""
        q = self.encoder_T.shared(self.standardize_target(x_T))
        return SharedRep(q.mean, q.logvar)

    def individual_source(self, x_S: torch.Tensor) -> SharedRep | None:
        """q_φS(y_T | x_S) as (mean, logvar), each (B, Y); None when Y = 0."""
        q_y = self.encode_source(x_S)[1]
        return None if q_y is None else SharedRep(q_y.mean, q_y.logvar)

    def individual_target(self, x_T: torch.Tensor) -> SharedRep | None:
        """q_φT(y_S | x_T) as (mean, logvar), each (B, Y); None when Y = 0."""
        q_y = self.encode_target(x_T)[1]
        return None if q_y is None else SharedRep(q_y.mean, q_y.logvar)

    # -- shaping (Eq. 10) ----------------------------------------------------------------
    def shaping_kl(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """KL(q_φS(c_T | x_S) ‖ q_φT(c_S | x_T)) in closed form: (B, D_S), (B, D_T) -> (B,).

        The reward term of Eq. 10 is ``−β`` times this."""
        q_s = self.encoder_S.shared(self.standardize_source(x_S))
        q_t = self.encoder_T.shared(self.standardize_target(x_T))
        if q_s.mean.shape[0] != q_t.mean.shape[0]:
            raise PvedError(
                f"source and target batches differ in size: {q_s.mean.shape[0]} vs "
                f"{q_t.mean.shape[0]}"
            )
        return kl_diag_gaussians(q_s.mean, q_s.logvar, q_t.mean, q_t.logvar)

    def shaping(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """Eq. 10's distance, the shared-posterior KL: (B,). See :meth:`shaping_kl`."""
        return self.shaping_kl(x_S, x_T)

    # -- predictions in raw units (diagnostics, tests, plots) ----------------------------
    @torch.no_grad()
    def predict_target(self, x_S: torch.Tensor) -> torch.Tensor:
        """Mean of p_θT(x_T | c_T, y_T) at the means of q_φS(c_T, y_T | x_S), raw units:
        (B, D_S) -> (B, D_T). The cross-agent prediction that Eq. 2 trains."""
        q_c, q_y = self.encode_source(x_S)
        mean = self.decoder_T(q_c.mean, None if q_y is None else q_y.mean)
        return self.target_norm.inverse(mean)

    @torch.no_grad()
    def predict_source(self, x_T: torch.Tensor) -> torch.Tensor:
        """Mean of p_θS(x_S | c_S, y_S) at the means of q_φT(c_S, y_S | x_T), raw units:
        (B, D_T) -> (B, D_S) (Eq. 6)."""
        q_c, q_y = self.encode_target(x_T)
        mean = self.decoder_S(q_c.mean, None if q_y is None else q_y.mean)
        return self.source_norm.inverse(mean)

    @torch.no_grad()
    def reconstruct_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Mean of p_θ'T(x_S | c_T) at the mean of q_φS(c_T | x_S), raw units (Eq. 8):
        (B, D_S) -> (B, D_S)."""
        q_c = self.encoder_S.shared(self.standardize_source(x_S))
        return self.source_norm.inverse(self.decoder_T_prime(q_c.mean))

    @torch.no_grad()
    def reconstruct_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Mean of p_θ'S(x_T | c_S) at the mean of q_φT(c_S | x_T), raw units (Eq. 8):
        (B, D_T) -> (B, D_T)."""
        q_c = self.encoder_T.shared(self.standardize_target(x_T))
        return self.target_norm.inverse(self.decoder_S_prime(q_c.mean))

    # -- the objective (Eq. 9) -----------------------------------------------------------
    def loss(
        self, x_S: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Eq. 9 on a paired batch of raw x_S (B, D_S) and x_T (B, D_T).

        Returns scalars (batch means): the five Eq. 9 terms ``L_ST, L_TS, L_SS, L_TT, L_C``
        (to maximise, as in the paper), their pieces ``loglik_XY`` and ``kl_XY`` (so
        ``L_XY = loglik_XY − kl_XY``), and ``total`` = −L to MINIMISE.
        """
        xs = self.standardize_source(x_S)
        xt = self.standardize_target(x_T)
        if xs.shape[0] != xt.shape[0]:
            raise PvedError(
                f"source and target batches differ in size: {xs.shape[0]} vs {xt.shape[0]}"
            )
        q_cT, q_yT = self.encoder_S(xs)  # q_φS(c_T, y_T | x_S)
        q_cS, q_yS = self.encoder_T(xt)  # q_φT(c_S, y_S | x_T)
        c_T = reparameterize(q_cT.mean, q_cT.logvar, generator)
        c_S = reparameterize(q_cS.mean, q_cS.logvar, generator)
        y_T = None if q_yT is None else reparameterize(q_yT.mean, q_yT.logvar, generator)
        y_S = None if q_yS is None else reparameterize(q_yS.mean, q_yS.logvar, generator)

        kl_cT = kl_standard_normal(q_cT.mean, q_cT.logvar)
        kl_cS = kl_standard_normal(q_cS.mean, q_cS.logvar)
        kl_yT = kl_standard_normal(*q_yT) if q_yT is not None else torch.zeros_like(kl_cT)
        kl_yS = kl_standard_normal(*q_yS) if q_yS is not None else torch.zeros_like(kl_cS)

        # Eq. 2: the source's posterior over the TARGET's factors reconstructs x_T.
        ll_ST = gaussian_log_likelihood(xt, self.decoder_T(c_T, y_T), self.decoder_T.logvar)
        # Eq. 6: the target's posterior over the SOURCE's factors reconstructs x_S.
        ll_TS = gaussian_log_likelihood(xs, self.decoder_S(c_S, y_S), self.decoder_S.logvar)
        # Eq. 8: each shared posterior alone reconstructs its OWN encoder's input.
        ll_SS = gaussian_log_likelihood(xs, self.decoder_T_prime(c_T), self.decoder_T_prime.logvar)
        ll_TT = gaussian_log_likelihood(xt, self.decoder_S_prime(c_S), self.decoder_S_prime.logvar)
        # Eq. 7: consistency of the two shared posteriors.
        kl_C = kl_diag_gaussians(q_cT.mean, q_cT.logvar, q_cS.mean, q_cS.logvar)

        parts = {
            "loglik_ST": ll_ST.mean(),
            "kl_ST": (kl_cT + kl_yT).mean(),
            "loglik_TS": ll_TS.mean(),
            "kl_TS": (kl_cS + kl_yS).mean(),
            "loglik_SS": ll_SS.mean(),
            "kl_SS": kl_cT.mean(),
            "loglik_TT": ll_TT.mean(),
            "kl_TT": kl_cS.mean(),
        }
        for term in ("ST", "TS", "SS", "TT"):
            parts[f"L_{term}"] = parts[f"loglik_{term}"] - parts[f"kl_{term}"]
        parts["L_C"] = -kl_C.mean()
        parts["total"] = -self.objective(parts)
        return parts

    def objective(self, parts: dict[str, torch.Tensor]) -> torch.Tensor:
        """Eq. 9 from the named terms: α1(L_ST + L_TS) + α2(L_SS + L_TT) + α3 L_C."""
        cfg = self.config
        return (
            cfg.alpha1 * (parts["L_ST"] + parts["L_TS"])
            + cfg.alpha2 * (parts["L_SS"] + parts["L_TT"])
            + cfg.alpha3 * parts["L_C"]
        )
