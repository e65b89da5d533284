"""The Gupta et al. 2017 baseline: "Learning Invariant Feature Spaces to Transfer Skills
with Reinforcement Learning" (ICLR 2017), the comparison method of paper IV.B.

Deterministic embeddings of the two agents' STATES into one feature space, trained on
time-paired states::

    f: s_S (B, S_S) -> (B, K)      g: s_T (B, S_T) -> (B, K)
    Dec_S: (B, K) -> (B, S_S)      Dec_T: (B, K) -> (B, S_T)

    recon_S = ‖s_S − Dec_S(f(s_S))‖²,   recon_T = ‖s_T − Dec_T(g(s_T))‖²,
    align   = ‖f(s_S) − g(s_T)‖²
    total   = w_S · recon_S + w_T · recon_T + w_align · align      (batch means, MINIMISED)

The autoencoder terms keep the embeddings informative (alignment alone is minimised by
mapping everything to one point). Transfer (Gupta's Eq. for r_transfer, the paper's
Eq. 10 slot): the shaping distance is ‖f(s_S) − g(s_T)‖, and the transfer stage adds
−β times it (β plays Gupta's α).

Inputs are full raw rows ``x = concat(s, a)`` like every model's; the actions are sliced
off (Gupta's features are functions of the state). States are standardised by the model
(``SharedSpaceModel``) and the squared errors are in standardised units.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TypeVar

import torch
from torch import nn

from pved.errors import PvedError
from pved.models.base import ModelConfig, ModelDims, SharedRep, SharedSpaceModel
from pved.models.pved import check_same_batch, encoder_trunk

__all__ = ["Gupta2017", "Gupta2017Config"]

#: The weights of the three loss terms, in the order they are logged.
LOSS_WEIGHTS = ("weight_recon_source", "weight_recon_target", "weight_align")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Gupta2017Config(ModelConfig):
    """Gupta et al. 2017 settings plus the shared training settings.

    Attributes:
        shared_dim: K, the dimension of the common feature space (10, like PVED's c, so
            a pair's ``shared_dim`` setting applies to both).
        hidden: units per hidden layer of every MLP (64, like PVED's).
        weight_recon_source: weight of the source autoencoder term.
        weight_recon_target: weight of the target autoencoder term.
        weight_align: weight of the alignment term ‖f(s_S) − g(s_T)‖².
    """

    shared_dim: int = 10
    hidden: int = 64
    weight_recon_source: float = 1.0
    weight_recon_target: float = 1.0
    weight_align: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.shared_dim < 1:
            raise PvedError(f"config: shared_dim must be >= 1, got {self.shared_dim}")
        if self.hidden < 1:
            raise PvedError(f"config: hidden must be >= 1, got {self.hidden}")
        for name in LOSS_WEIGHTS:
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise PvedError(f"config: {name} must be a finite number >= 0, got {value}")


Term = TypeVar("Term", float, torch.Tensor)


def weighted_total(cfg: Gupta2017Config, parts: Mapping[str, Term]) -> Term:
    """The loss to minimise from its three terms (module docstring): tensors in
    :meth:`Gupta2017.loss`, floats in the numpy gradient's logged parts."""
    return (
        cfg.weight_recon_source * parts["recon_S"]
        + cfg.weight_recon_target * parts["recon_T"]
        + cfg.weight_align * parts["align"]
    )


def _mlp(in_dim: int, hidden: int, out_dim: int) -> nn.Sequential:
    """Three linear layers, ReLU between: (B, in_dim) -> (B, out_dim)."""
    return nn.Sequential(encoder_trunk(in_dim, hidden), nn.Linear(hidden, out_dim))


class Gupta2017(SharedSpaceModel):
    """Invariant feature spaces of Gupta et al. 2017 (module docstring): ``embed_S`` = f,
    ``embed_T`` = g, ``decode_S`` = Dec_S, ``decode_T`` = Dec_T."""

    name = "gupta2017"
    config_class = Gupta2017Config
    config: Gupta2017Config

    def __init__(self, dims: ModelDims, config: Gupta2017Config | None = None):
        super().__init__(dims, config if config is not None else self.config_class())
        if min(dims.source_state_dim, dims.target_state_dim) < 1:
            raise PvedError(
                f"model {self.name!r} embeds the robot states, but a state dim is 0 "
                f"(source {dims.source_state_dim}, target {dims.target_state_dim})"
            )
        k, hid = self.config.shared_dim, self.config.hidden
        self.embed_S = _mlp(dims.source_state_dim, hid, k)
        self.embed_T = _mlp(dims.target_state_dim, hid, k)
        self.decode_S = _mlp(k, hid, dims.source_state_dim)
        self.decode_T = _mlp(k, hid, dims.target_state_dim)

    def states_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Raw x_S (B, D_S) -> standardised state s_S (B, S_S)."""
        return self.standardize_source(x_S)[:, : self.source_state_dim]

    def states_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Raw x_T (B, D_T) -> standardised state s_T (B, S_T)."""
        return self.standardize_target(x_T)[:, : self.target_state_dim]

    def shared_source(self, x_S: torch.Tensor) -> SharedRep:
        """f(s_S) as (point (B, K), None)."""
        return SharedRep(self.embed_S(self.states_source(x_S)), None)

    def shared_target(self, x_T: torch.Tensor) -> SharedRep:
        """g(s_T) as (point (B, K), None)."""
        return SharedRep(self.embed_T(self.states_target(x_T)), None)

    def shaping(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """‖f(s_S) − g(s_T)‖, Gupta's transfer distance: (B,)."""
        f = self.shared_source(x_S).mean
        g = self.shared_target(x_T).mean
        check_same_batch(f, g)
        return torch.linalg.vector_norm(f - g, dim=-1)

    def loss(
        self, x_S: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Batch means of ``recon_S``, ``recon_T``, ``align`` and their weighted sum
        ``total`` (module docstring) on raw x_S (B, D_S), x_T (B, D_T). Deterministic:
        ``generator`` is unused."""
        s_S = self.states_source(x_S)
        s_T = self.states_target(x_T)
        check_same_batch(s_S, s_T)
        f, g = self.embed_S(s_S), self.embed_T(s_T)
        parts = {
            "recon_S": (self.decode_S(f) - s_S).pow(2).sum(dim=-1).mean(),
            "recon_T": (self.decode_T(g) - s_T).pow(2).sum(dim=-1).mean(),
            "align": (f - g).pow(2).sum(dim=-1).mean(),
        }
        parts["total"] = weighted_total(self.config, parts)
        return parts
