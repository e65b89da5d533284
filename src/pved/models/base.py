"""The one interface every learned shared-space model implements.

PVED, its ablations (state-only, shared-only, det-shared, VAE-posterior) and the Gupta et
al. 2017 baseline all map a source state-action vector ``x_S = concat(s_S, a_S)`` of dim
``D_S`` and a target one ``x_T = concat(s_T, a_T)`` of dim ``D_T`` to a shared
representation, are trained on paired rows ``(x_S, x_T)``, and give the transfer stage a
non-negative distance whose negative times β is the shaping reward (Eq. 10).

Every model carries the standardisation statistics of its paired training data as
buffers and applies them itself (DESIGN.md "What each stage sees"): callers always pass
raw, unstandardised vectors, so pairing, training and shaping cannot disagree on scaling.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch
from torch import nn

from pved.checks import check_int, check_number, check_seed
from pved.errors import PvedError
from pved.models.distributions import kl_diag_gaussians


@dataclasses.dataclass(frozen=True, kw_only=True)
class ModelConfig:
    """Training settings every model shares; model configs subclass it.

    Attributes:
        lr: Adam learning rate (paper: 1e-4).
        batch_size: minibatch size (paper: 256).
        epochs: passes over the training split.
        val_fraction: share of the pairs held out for validation losses, in [0, 1).
        seed: seeds the initialisation, the split, the shuffling and the sampling noise.
        checkpoint_every: save a resumable checkpoint every this many epochs (and at the end).
        grad_clip: clip the global gradient norm to this value; None leaves it unclipped.
    """

    lr: float = 1e-4
    batch_size: int = 256
    epochs: int = 100
    val_fraction: float = 0.1
    seed: int = 0
    checkpoint_every: int = 10
    grad_clip: float | None = None

    def __post_init__(self) -> None:
        check_number("lr", self.lr, low=0.0, low_open=True)
        check_int("batch_size", self.batch_size, low=1)
        # zero epochs would save the untrained initialisation as a trained model
        check_int("epochs", self.epochs, low=1)
        check_number("val_fraction", self.val_fraction, low=0.0, high=1.0, high_open=True)
        check_seed("seed", self.seed)
        check_int("checkpoint_every", self.checkpoint_every, low=1)
        if self.grad_clip is not None:
            check_number("grad_clip", self.grad_clip, low=0.0, low_open=True)


def config_to_dict(config: ModelConfig) -> dict[str, Any]:
    """A config as plain values (loads back under ``torch.load(weights_only=True)``)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}


def config_from_dict(cls: type[ModelConfig], values: dict[str, Any]) -> ModelConfig:
    """Rebuild a config of class ``cls``; unknown keys raise :class:`PvedError`."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise PvedError(f"{cls.__name__} has no field(s) {', '.join(unknown)}")
    # JSON and torch round trips turn tuples into lists; frozen configs keep tuples.
    clean: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return cls(**clean)


@dataclasses.dataclass(frozen=True)
class ModelDims:
    """Input layout of a model: ``x_S`` has ``source_dim`` entries, the first
    ``source_state_dim`` of them the robot state s_S and the rest the action a_S; the same
    for ``x_T``. Kept so that state-only variants can slice off the actions."""

    source_dim: int
    target_dim: int
    source_state_dim: int
    target_state_dim: int

    def __post_init__(self) -> None:
        for side in ("source", "target"):
            dim = getattr(self, f"{side}_dim")
            state = getattr(self, f"{side}_state_dim")
            if not isinstance(dim, int | np.integer) or dim < 1:
                raise PvedError(f"{side} dim must be a positive integer, got {dim!r}")
            if not isinstance(state, int | np.integer) or not 0 <= state <= dim:
                raise PvedError(f"{side} state dim must be in [0, {dim}], got {state!r}")

    @property
    def source_action_dim(self) -> int:
        return self.source_dim - self.source_state_dim

    @property
    def target_action_dim(self) -> int:
        return self.target_dim - self.target_state_dim

    def as_dict(self) -> dict[str, int]:
        return {f.name: int(getattr(self, f.name)) for f in dataclasses.fields(self)}


class SharedRep(NamedTuple):
    """A shared representation: a diagonal Gaussian ``(mean, logvar)`` of shape (B, K), or
    a point ``(mean, None)`` for deterministic models."""

    mean: torch.Tensor
    logvar: torch.Tensor | None


class Standardizer(nn.Module):
    """Per-dimension affine standardisation ``(x − mean) / std`` held as buffers, so that
    it travels in the model's state dict."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @torch.no_grad()
    def fit(self, x: torch.Tensor) -> None:
        """Set the statistics from data ``x`` of shape (N, D). A dimension that is constant
        (std tiny relative to its magnitude) keeps std 1, so it standardises to 0 instead of
        blowing float noise up into a large input."""
        if x.ndim != 2 or x.shape[1] != self.mean.shape[0] or x.shape[0] < 1:
            raise PvedError(
                f"standardisation needs data of shape (N>=1, {self.mean.shape[0]}), "
                f"got {tuple(x.shape)}"
            )
        x64 = x.double()
        mean = x64.mean(dim=0)
        std = x64.std(dim=0, unbiased=False)
        constant = std <= 1e-6 * (1.0 + mean.abs())
        std = torch.where(constant, torch.ones_like(std), std)
        self.mean.copy_(mean.to(self.mean.dtype))
        self.std.copy_(std.to(self.std.dtype))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, D) raw -> (B, D) standardised, in the buffers' dtype. The offset is removed
        in the input's own dtype first, so float64 inputs with large offsets keep their
        precision."""
        if x.dtype != self.mean.dtype:
            return ((x - self.mean.to(x.dtype)) / self.std.to(x.dtype)).to(self.mean.dtype)
        return (x - self.mean) / self.std

    def inverse(self, z: torch.Tensor) -> torch.Tensor:
        """(B, D) standardised -> (B, D) raw."""
        return z * self.std + self.mean


class SharedSpaceModel(nn.Module, abc.ABC):
    """Abstract base of every learned model that pairs a source and a target agent.

    Subclasses set ``name`` (its registry key) and ``config_class``, build their networks
    in ``__init__(dims, config)`` and implement the four abstract methods. All methods take
    raw inputs: ``x_S`` of shape (B, D_S), ``x_T`` of shape (B, D_T), float32.
    """

    name: ClassVar[str] = ""
    config_class: ClassVar[type[ModelConfig]] = ModelConfig

    def __init__(self, dims: ModelDims, config: ModelConfig):
        super().__init__()
        if not isinstance(config, self.config_class):
            raise PvedError(
                f"model {self.name!r} needs a {self.config_class.__name__}, "
                f"got {type(config).__name__}"
            )
        self.dims = dims
        self.config = config
        #: Epochs of training done so far (fractional within an epoch), set by the
        #: trainer before each step; infinite outside training, where no warm-up applies.
        self.epochs_done = math.inf
        #: Plain facts about this model (pair, dataset, seed...): written by
        #: :func:`pved.models.save_model`, restored by :func:`pved.models.load_model`.
        self.metadata: dict[str, Any] = {}
        self.source_norm = Standardizer(dims.source_dim)
        self.target_norm = Standardizer(dims.target_dim)

    @property
    def warmup_epochs_done(self) -> float:
        """Where training stands for a term that warms up: ``epochs_done`` in training
        mode, infinite otherwise (validation and use see the full objective)."""
        return self.epochs_done if self.training else math.inf

    # -- layout ------------------------------------------------------------------------
    @property
    def source_dim(self) -> int:
        """D_S, the length of a source row ``concat(s_S, a_S)``."""
        return self.dims.source_dim

    @property
    def target_dim(self) -> int:
        """D_T, the length of a target row ``concat(s_T, a_T)``."""
        return self.dims.target_dim

    @property
    def source_state_dim(self) -> int:
        """How many leading entries of a source row are the robot state s_S."""
        return self.dims.source_state_dim

    @property
    def target_state_dim(self) -> int:
        """How many leading entries of a target row are the robot state s_T."""
        return self.dims.target_state_dim

    # -- standardisation ---------------------------------------------------------------
    def fit_standardization(self, x_S: torch.Tensor, x_T: torch.Tensor) -> None:
        """Set the stored statistics from raw paired training data (N, D_S), (N, D_T)."""
        self.source_norm.fit(self.check_source(x_S))
        self.target_norm.fit(self.check_target(x_T))

    def check_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Check that ``x_S`` is a (B, D_S) tensor; returns it."""
        return _check_input(x_S, self.dims.source_dim, "source")

    def check_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Check that ``x_T`` is a (B, D_T) tensor; returns it."""
        return _check_input(x_T, self.dims.target_dim, "target")

    def standardize_source(self, x_S: torch.Tensor) -> torch.Tensor:
        """Raw (B, D_S) -> standardised (B, D_S)."""
        return self.source_norm(self.check_source(x_S))

    def standardize_target(self, x_T: torch.Tensor) -> torch.Tensor:
        """Raw (B, D_T) -> standardised (B, D_T)."""
        return self.target_norm(self.check_target(x_T))

    # -- the contract ------------------------------------------------------------------
    @abc.abstractmethod
    def loss(
        self, x_S: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """Training loss on a paired batch (B, D_S), (B, D_T).

        Returns scalar tensors: ``"total"`` (to MINIMISE, differentiable) and the model's
        named parts (batch means), such that ``total`` can be recomputed from the parts.
        ``generator`` makes any sampling noise reproducible.
        """

    @abc.abstractmethod
    def shared_source(self, x_S: torch.Tensor) -> SharedRep:
        """The shared representation inferred from the source: (B, D_S) -> (B, K)."""

    @abc.abstractmethod
    def shared_target(self, x_T: torch.Tensor) -> SharedRep:
        """The shared representation inferred from the target: (B, D_T) -> (B, K)."""

    @abc.abstractmethod
    def shaping(self, x_S: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """Non-negative distance (B,) between the shared representations of time-matched
        source and target rows; the shaping reward is ``−β · shaping`` (Eq. 10). Call under
        ``torch.no_grad()`` in RL."""

    def shaping_between(self, source: SharedRep, target: SharedRep) -> torch.Tensor:
        """Eq. 10's distance from the two shared representations, each (B, K) -> (B,):
        the closed-form KL(q_S ‖ q_T) between diagonal Gaussians (source first, as in
        Eq. 10), or ‖source − target‖ between points (the deterministic models).

        Every model's :meth:`shaping` equals ``shaping_between(shared_source(x_S),
        shared_target(x_T))`` bit for bit (a test checks each registered model), so the
        transfer stage can encode the source bank once per run and give only the target
        half per step (``pved.transfer.source_cache``). A model whose distance is not of
        this form overrides it."""
        if source.mean.shape[0] != target.mean.shape[0]:
            raise PvedError(
                f"source and target batches differ in size: "
                f"{source.mean.shape[0]} vs {target.mean.shape[0]}"
            )
        if source.logvar is None or target.logvar is None:
            return torch.linalg.vector_norm(source.mean - target.mean, dim=-1)
        return kl_diag_gaussians(source.mean, source.logvar, target.mean, target.logvar)

    def individual_source(self, x_S: torch.Tensor) -> SharedRep | None:
        """The source's individual representation (B, K_y), or None for models without one."""
        return None

    def individual_target(self, x_T: torch.Tensor) -> SharedRep | None:
        """The target's individual representation (B, K_y), or None for models without one."""
        return None

    def spec(self) -> dict[str, Any]:
        """What is needed to rebuild this model before loading its state dict: registry
        name, dims and config, as plain values."""
        return {
            "name": self.name,
            "dims": self.dims.as_dict(),
            "config": config_to_dict(self.config),
        }


def _check_input(x: Any, dim: int, side: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise PvedError(f"{side} input must be a torch.Tensor, got {type(x).__name__}")
    if x.ndim != 2 or x.shape[1] != dim:
        raise PvedError(f"{side} input must have shape (B, {dim}), got {tuple(x.shape)}")
    if not torch.is_floating_point(x):
        raise PvedError(f"{side} input must be a float tensor, got {x.dtype}")
    return x
