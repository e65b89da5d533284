"""Registry of learned models, and their weights files.

Adding a model (an ablation, a baseline) = one new file with a :class:`SharedSpaceModel`
subclass + one entry in :data:`MODELS`.

A weights file is a plain dict loadable with ``torch.load(weights_only=True)``::

    {"format": "pved-model", "format_version": 1, "name": "pved",
     "dims": {...}, "config": {...}, "state_dict": {...}, "metadata": {...}}

The state dict includes the standardisation statistics (DESIGN.md "What each stage sees").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pved.errors import PvedError
from pved.models.base import ModelConfig, ModelDims, SharedSpaceModel, config_from_dict
from pved.models.gupta import Gupta2017
from pved.models.pved import PVED
from pved.models.variants import PVEDVAE, PVEDDetShared, PVEDSharedOnly, PVEDStateOnly
from pved.runs import atomic_torch_save, safe_torch_load, to_jsonable

#: Model name -> class. Names are the ones the CLI and configs use.
MODELS: dict[str, type[SharedSpaceModel]] = {
    "pved": PVED,
    # The ablations of paper IV.B and the Gupta et al. 2017 baseline.
    "pved-state-only": PVEDStateOnly,
    "pved-shared-only": PVEDSharedOnly,
    "pved-det-shared": PVEDDetShared,
    "pved-vae": PVEDVAE,
    "gupta2017": Gupta2017,
}

MODEL_FORMAT = "pved-model"
MODEL_FORMAT_VERSION = 1


def model_class(name: str) -> type[SharedSpaceModel]:
    """The registered class for ``name``; an unknown name raises :class:`PvedError`."""
    try:
        return MODELS[name]
    except (KeyError, TypeError):
        raise PvedError(
            f"unknown model {name!r}; known models: {', '.join(sorted(MODELS))}"
        ) from None


def build_model(name: str, dims: ModelDims, config: ModelConfig | None = None) -> SharedSpaceModel:
    """A fresh, untrained model ``name`` for inputs of layout ``dims``.

    ``config`` defaults to the model's own config class with its defaults; a config of
    the wrong class raises :class:`PvedError`.
    """
    cls = model_class(name)
    if config is None:
        config = cls.config_class()
    return cls(dims, config)


def save_model(
    model: SharedSpaceModel, path: Path | str, metadata: dict[str, Any] | None = None
) -> Path:
    """Atomically write ``model`` (weights, standardisation, dims, config) and plain
    metadata (e.g. pair, dataset, seed) to ``path``; returns the path. The metadata saved
    is ``model.metadata`` updated with ``metadata``."""
    path = Path(path)
    payload = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        **model.spec(),
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "metadata": to_jsonable({**model.metadata, **(metadata or {})}),
    }
    atomic_torch_save(path, payload)
    return path


def load_model(path: Path | str, expected_dims: ModelDims | None = None) -> SharedSpaceModel:
    """Load a model written by :func:`save_model`, without executing code, in eval mode.

    The file's metadata is on ``model.metadata``. A missing, corrupt or foreign
    file, a file whose weights do not fit its own dims, or (when given) ``expected_dims``
    that differ from the file's raise :class:`PvedError` naming the problem.
    """
    path = Path(path)
    payload = safe_torch_load(path)
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        raise PvedError(f"{path} is not a pved model file (no '{MODEL_FORMAT}' header)")
    if payload.get("format_version") != MODEL_FORMAT_VERSION:
        raise PvedError(
            f"{path}: model format version {payload.get('format_version')!r} is not "
            f"supported (expected {MODEL_FORMAT_VERSION})"
        )
    for key in ("name", "dims", "config", "state_dict"):
        if key not in payload:
            raise PvedError(f"{path}: model file lacks its {key!r} entry")
    cls = model_class(payload["name"])
    try:
        dims = ModelDims(**payload["dims"])
    except TypeError as exc:
        raise PvedError(f"{path}: bad dims entry ({exc})") from None
    if expected_dims is not None and dims != expected_dims:
        raise PvedError(
            f"{path}: model dims {dims.as_dict()} != expected {expected_dims.as_dict()}"
        )
    config = config_from_dict(cls.config_class, dict(payload["config"]))
    model = cls(dims, config)
    try:
        model.load_state_dict(payload["state_dict"], strict=True)
    except (RuntimeError, TypeError, AttributeError) as exc:
        detail = " ".join(str(exc).split())[:200]
        raise PvedError(
            f"{path}: weights do not fit model {cls.name!r} {dims.as_dict()}: {detail}"
        ) from None
    model.metadata = dict(payload.get("metadata") or {})
    model.eval()
    return model


__all__ = [
    "MODELS",
    "build_model",
    "load_model",
    "model_class",
    "save_model",
]
