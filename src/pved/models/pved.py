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
from collections.abc import Mapping
from typing import ClassVar, TypeVar

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
        consistency_warmup_epochs: α3 rises linearly from 0 to its value over this many
            epochs of training (0: from the start). Not in the paper: without it the
            consistency term pulls both shared posteriors onto the prior before the
            decoders use them, and on Walker2d-Hopper they never left it
            (docs/decisions.md, "Consistency warm-up").

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
    consistency_warmup_epochs: float = 4.0

    def __post_init__(self) -> None:
        super().__post_init__()
        warmup = self.consistency_warmup_epochs
        if not (warmup >= 0 and math.isfinite(warmup)):
            raise PvedError(
                "config: consistency_warmup_epochs must be a finite number >= 0, "
                f"got {self.consistency_warmup_epochs}"
            )
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


def encoder_trunk(in_dim: int, hidden: int) -> nn.Sequential:
    """The first two layers of every encoder, (B, in_dim) -> (B, hidden), ReLU (paper III.G);
    the third layer is the model's own head(s)."""
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())


def to_diag_gaussian(out: torch.Tensor) -> DiagGaussian:
    """A Gaussian head's output (B, 2K) as (mean, logvar), each (B, K), the log-variance
    softly bounded to :data:`ENCODER_LOGVAR_BOUNDS`."""
    mean, raw_logvar = out.chunk(2, dim=-1)
    return DiagGaussian(mean, soft_clamp(raw_logvar, *ENCODER_LOGVAR_BOUNDS))


def check_same_batch(x_S: torch.Tensor, x_T: torch.Tensor) -> None:
    """Paired inputs must have as many source as target rows."""
    if x_S.shape[0] != x_T.shape[0]:
        raise PvedError(
            f"source and target batches differ in size: {x_S.shape[0]} vs {x_T.shape[0]}"
        )


class GaussianEncoder(nn.Module):
    """q(c, y | x): a trunk shared by both subspaces, then one head per subspace.

    (B, D) -> (DiagGaussian over c of shape (B, C), DiagGaussian over y (B, Y) or None).
    ReLU activations (paper III.G).
    """

    def __init__(self, in_dim: int, shared_dim: int, individual_dim: int, hidden: int):
        super().__init__()
        self.trunk = encoder_trunk(in_dim, hidden)
        self.head_c = nn.Linear(hidden, 2 * shared_dim)
        self.head_y = nn.Linear(hidden, 2 * individual_dim) if individual_dim > 0 else None

    def forward(self, x: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        h = self.trunk(x)
        q_y = to_diag_gaussian(self.head_y(h)) if self.head_y is not None else None
        return to_diag_gaussian(self.head_c(h)), q_y

    def shared(self, x: torch.Tensor) -> DiagGaussian:
        """Only the c posterior (skips the y head): (B, D) -> (B, C)."""
        return to_diag_gaussian(self.head_c(self.trunk(x)))


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


def decoder_from_config(cfg: PVEDConfig, individual_dim: int, out_dim: int) -> Decoder:
    """A :class:`Decoder` with ``cfg``'s shared dim, widths, slope and likelihood variance;
    ``individual_dim=0`` gives a c-only decoder (Eq. 8)."""
    return Decoder(
        cfg.shared_dim,
        individual_dim,
        out_dim,
        cfg.hidden,
        cfg.leaky_slope,
        cfg.decoder_variance == "learned",
        cfg.min_decoder_std,
    )


def consistency_scale(cfg: PVEDConfig, epochs_done: float) -> float:
    """The factor on α3 after ``epochs_done`` epochs of training: ``epochs_done /
    cfg.consistency_warmup_epochs`` until it reaches 1, then 1 (always 1 without warm-up)."""
    if cfg.consistency_warmup_epochs <= 0:
        return 1.0
    return min(1.0, max(0.0, epochs_done) / cfg.consistency_warmup_epochs)


Term = TypeVar("Term", float, torch.Tensor)


def eq9_objective(
    cfg: PVEDConfig, parts: Mapping[str, Term], epochs_done: float = math.inf
) -> Term:
    """Eq. 9 from the named terms: α1(L_ST + L_TS) + α2(L_SS + L_TT) + α3 L_C (to maximise),
    with α3 scaled by :func:`consistency_scale` while ``epochs_done`` is in the warm-up
    (the default, no epoch count, is the paper's objective). The terms are tensors
    (autograd training, validation) or floats (the numpy gradient's logged parts)."""
    return (
        cfg.alpha1 * (parts["L_ST"] + parts["L_TS"])
        + cfg.alpha2 * (parts["L_SS"] + parts["L_TT"])
        + consistency_scale(cfg, epochs_done) * cfg.alpha3 * parts["L_C"]
    )


class PVED(SharedSpaceModel):
    """The paired variational encoder-decoder (see the module docstring for Eqs. 2–10).

    Two switches, off here, give two of the paper's ablations (IV.B) the same networks
    and objective "with the other components fixed" (``pved.models.variants``):
    ``states_only`` narrows what the networks see of a row x = (s, a) to its state s, and
    ``crossed_posteriors = False`` feeds each (c, y) decoder its own agent's posterior.
    """

    name = "pved"
    # Typed as the base's, not type[PVEDConfig]: a variant's config class may fix a field
    # (init=False), so its constructor is not PVEDConfig's.
    config_class: ClassVar[type[ModelConfig]] = PVEDConfig
    config: PVEDConfig
    #: The networks see (and the decoders reconstruct) only the state s of each row.
    states_only: ClassVar[bool] = False
    #: Eqs. 2 and 6 as in the paper: the posterior inferred from x_S feeds p_θT (which
    #: reconstructs x_T) and the one inferred from x_T feeds p_θS. False: each agent's own.
    crossed_posteriors: ClassVar[bool] = True

    def __init__(self, dims: ModelDims, config: PVEDConfig | None = None):
        super().__init__(dims, config if config is not None else self.config_class())
        cfg = self.config
        c_dim, y_dim, hid = cfg.shared_dim, cfg.individual_dim, cfg.hidden
        #: How many leading entries of x_S / x_T the networks see: all, or the state.
        self.source_width = dims.source_state_dim if self.states_only else dims.source_dim
        self.target_width = dims.target_state_dim if self.states_only else dims.target_dim
        if min(self.source_width, self.target_width) < 1:
            raise PvedError(
                f"model {self.name!r} sees only the robot states, but a state dim is 0 "
                f"(source {dims.source_state_dim}, target {dims.target_state_dim})"
            )
        w_S, w_T = self.source_width, self.target_width

        # q_φS(c_T, y_T | s_S, a_S) and q_φT(c_S, y_S | s_T, a_T)
        self.encoder_S = GaussianEncoder(w_S, c_dim, y_dim, hid)
        self.encoder_T = GaussianEncoder(w_T, c_dim, y_dim, hid)
        # p_θT(s_T, a_T | c_T, y_T) (Eq. 2) and p_θS(s_S, a_S | c_S, y_S) (Eq. 6)
        self.decoder_T = decoder_from_config(cfg, y_dim, w_T)
        self.decoder_S = decoder_from_config(cfg, y_dim, w_S)
        # p_θ'T(s_S, a_S | c_T) and p_θ'S(s_T, a_T | c_S) (Eq. 8)
        self.decoder_T_prime = decoder_from_config(cfg, 0, w_S)
        self.decoder_S_prime = decoder_from_config(cfg, 0, w_T)

    # -- what the networks see -----------------------------------------------------------
    def features_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Raw x_S (B, D_S) -> the standardised entries the networks see, (B, W_S): all of
        them, or the state's only when ``states_only`` (W_S = D_S or S_S)."""
        return self.standardize_source(x_S)[:, : self.source_width]

    def features_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Raw x_T (B, D_T) -> the standardised entries the networks see, (B, W_T)."""
        return self.standardize_target(x_T)[:, : self.target_width]

    def features_to_raw_source(self, z: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`features_source`: (B, W_S) standardised -> (B, W_S) raw."""
        width = self.source_width
        return z * self.source_norm.std[:width] + self.source_norm.mean[:width]

    def features_to_raw_target(self, z: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`features_target`: (B, W_T) standardised -> (B, W_T) raw."""
        width = self.target_width
        return z * self.target_norm.std[:width] + self.target_norm.mean[:width]

    # -- posteriors ----------------------------------------------------------------------
    def encode_source(self, x_S: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        """q_φS(c_T, y_T | x_S) from raw x_S (B, D_S): ((B, C), (B, Y) or None)."""
        return self.encoder_S(self.features_source(x_S))

    def encode_target(self, x_T: torch.Tensor) -> tuple[DiagGaussian, DiagGaussian | None]:
        """q_φT(c_S, y_S | x_T) from raw x_T (B, D_T): ((B, C), (B, Y) or None)."""
        return self.encoder_T(self.features_target(x_T))

    def shared_source(self, x_S: torch.Tensor) -> SharedRep:
        """q_φS(c_T | x_S) as (mean, logvar), each (B, C)."""
        q = self.encoder_S.shared(self.features_source(x_S))
        return SharedRep(q.mean, q.logvar)

    def shared_target(self, x_T: torch.Tensor) -> SharedRep:
        """q_φT(c_S | x_T) as (mean, logvar), each (B, C)."""
        q = self.encoder_T.shared(self.features_target(x_T))
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
        q_s = self.encoder_S.shared(self.features_source(x_S))
        q_t = self.encoder_T.shared(self.features_target(x_T))
        check_same_batch(q_s.mean, q_t.mean)
        return kl_diag_gaussians(q_s.mean, q_s.logvar, q_t.mean, q_t.logvar)

    def shaping(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """Eq. 10's distance, the shared-posterior KL: (B,). See :meth:`shaping_kl`."""
        return self.shaping_kl(x_S, x_T)

    # -- predictions in raw units (diagnostics, tests, plots) ----------------------------
    @torch.no_grad()
    def predict_target(self, x_S: torch.Tensor) -> torch.Tensor:
        """Mean of p_θT(x_T | c_T, y_T) at the means of q_φS(c_T, y_T | x_S), raw units:
        (B, D_S) -> (B, W_T). The cross-agent prediction that Eq. 2 trains."""
        q_c, q_y = self.encode_source(x_S)
        mean = self.decoder_T(q_c.mean, None if q_y is None else q_y.mean)
        return self.features_to_raw_target(mean)

    @torch.no_grad()
    def predict_source(self, x_T: torch.Tensor) -> torch.Tensor:
        """Mean of p_θS(x_S | c_S, y_S) at the means of q_φT(c_S, y_S | x_T), raw units:
        (B, D_T) -> (B, W_S) (Eq. 6)."""
        q_c, q_y = self.encode_target(x_T)
        mean = self.decoder_S(q_c.mean, None if q_y is None else q_y.mean)
        return self.features_to_raw_source(mean)

    @torch.no_grad()
    def reconstruct_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Mean of p_θ'T(x_S | c_T) at the mean of q_φS(c_T | x_S), raw units (Eq. 8):
        (B, D_S) -> (B, W_S)."""
        q_c = self.encoder_S.shared(self.features_source(x_S))
        return self.features_to_raw_source(self.decoder_T_prime(q_c.mean))

    @torch.no_grad()
    def reconstruct_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Mean of p_θ'S(x_T | c_S) at the mean of q_φT(c_S | x_T), raw units (Eq. 8):
        (B, D_T) -> (B, W_T)."""
        q_c = self.encoder_T.shared(self.features_target(x_T))
        return self.decode_target_shared(q_c.mean)

    @torch.no_grad()
    def decode_target_shared(self, c: torch.Tensor) -> torch.Tensor:
        """Mean of p_θ'S(x_T | c) (Eq. 8) at shared codes ``c`` (B, C), raw units: (B, W_T).

        Trained on the target's own code q_φT(c_S | x_T); Eq. 7 pulls the source's code
        q_φS(c_T | x_S) of a paired row onto it, so at the source's code it gives the
        target state-action the model pairs with the source's (``pved-prior``,
        :mod:`pved.transfer.prior_guide`)."""
        return self.features_to_raw_target(self.decoder_S_prime(c))

    # -- the objective (Eq. 9) -----------------------------------------------------------
    def loss(
        self, x_S: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Eq. 9 on a paired batch of raw x_S (B, D_S) and x_T (B, D_T).

        Returns scalars (batch means): the five Eq. 9 terms ``L_ST, L_TS, L_SS, L_TT, L_C``
        (to maximise, as in the paper), their pieces ``loglik_XY`` and ``kl_XY`` (so
        ``L_XY = loglik_XY − kl_XY``), and ``total`` = −L to MINIMISE.

        With ``crossed_posteriors = False`` (pved-vae) only the inputs of p_θT and p_θS
        change: each is fed, and its Eq. 2 / Eq. 6 prior KL taken on, its own agent's
        posterior; Eqs. 7 and 8 are the same computation.
        """
        xs = self.features_source(x_S)
        xt = self.features_target(x_T)
        check_same_batch(xs, xt)
        # Named by the data they are inferred from: "_S" from x_S, "_T" from x_T. In PVED
        # the one from x_S is q_φS(c_T, y_T | x_S), the target's factors (Eq. 2).
        q_c_S, q_y_S = self.encoder_S(xs)
        q_c_T, q_y_T = self.encoder_T(xt)
        c_S = reparameterize(q_c_S.mean, q_c_S.logvar, generator)
        c_T = reparameterize(q_c_T.mean, q_c_T.logvar, generator)
        y_S = None if q_y_S is None else reparameterize(q_y_S.mean, q_y_S.logvar, generator)
        y_T = None if q_y_T is None else reparameterize(q_y_T.mean, q_y_T.logvar, generator)

        kl_c_S = kl_standard_normal(q_c_S.mean, q_c_S.logvar)
        kl_c_T = kl_standard_normal(q_c_T.mean, q_c_T.logvar)
        kl_y_S = kl_standard_normal(*q_y_S) if q_y_S is not None else torch.zeros_like(kl_c_S)
        kl_y_T = kl_standard_normal(*q_y_T) if q_y_T is not None else torch.zeros_like(kl_c_T)

        # Eqs. 2 and 6: PVED reconstructs x_T from the posterior inferred from x_S and
        # x_S from the one inferred from x_T; pved-vae each from its own.
        from_S = (c_S, y_S, kl_c_S + kl_y_S)
        from_T = (c_T, y_T, kl_c_T + kl_y_T)
        (c_in_T, y_in_T, kl_in_T), (c_in_S, y_in_S, kl_in_S) = (
            (from_S, from_T) if self.crossed_posteriors else (from_T, from_S)
        )
        ll_ST = gaussian_log_likelihood(xt, self.decoder_T(c_in_T, y_in_T), self.decoder_T.logvar)
        ll_TS = gaussian_log_likelihood(xs, self.decoder_S(c_in_S, y_in_S), self.decoder_S.logvar)
        # Eq. 8: each shared posterior alone reconstructs its OWN encoder's input.
        ll_SS = gaussian_log_likelihood(xs, self.decoder_T_prime(c_S), self.decoder_T_prime.logvar)
        ll_TT = gaussian_log_likelihood(xt, self.decoder_S_prime(c_T), self.decoder_S_prime.logvar)
        # Eq. 7: consistency of the two shared posteriors, the one from x_S first.
        kl_C = kl_diag_gaussians(q_c_S.mean, q_c_S.logvar, q_c_T.mean, q_c_T.logvar)

        parts = {
            "loglik_ST": ll_ST.mean(),
            "kl_ST": kl_in_T.mean(),
            "loglik_TS": ll_TS.mean(),
            "kl_TS": kl_in_S.mean(),
            "loglik_SS": ll_SS.mean(),
            "kl_SS": kl_c_S.mean(),
            "loglik_TT": ll_TT.mean(),
            "kl_TT": kl_c_T.mean(),
        }
        for term in ("ST", "TS", "SS", "TT"):
            parts[f"L_{term}"] = parts[f"loglik_{term}"] - parts[f"kl_{term}"]
        parts["L_C"] = -kl_C.mean()
        parts["total"] = -self.objective(parts)
        return parts

    def objective(self, parts: dict[str, torch.Tensor]) -> torch.Tensor:
        """Eq. 9 from the named terms: α1(L_ST + L_TS) + α2(L_SS + L_TT) + α3 L_C."""
        return eq9_objective(self.config, parts, self.warmup_epochs_done)
