"""Training any registered shared-space model on a paired dataset.

``train_model`` takes raw paired rows (``x_source[i]`` time-matched with ``x_target[i]``),
holds out a validation split, fits the model's standardisation on the training split,
and runs Adam over shuffled minibatches. With a :class:`pved.runs.Run` it logs every
named loss part per epoch (``train/<part>``, ``val/<part>``), checkpoints every
``config.checkpoint_every`` epochs and at the end, and resumes from the newest checkpoint
so that an interrupted run continues exactly where it stopped.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

import numpy as np
import torch
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from pved.errors import PvedError
from pved.models.base import ModelConfig, ModelDims, SharedSpaceModel
from pved.models.numpy_grad import NumpyStep, numpy_step, numpy_trainable
from pved.models.registry import build_model, load_model, model_class, save_model
from pved.runs import Run

__all__ = [
    "BACKENDS",
    "evaluate_model",
    "load_model",  # re-exported: weights files belong with training for most callers
    "save_model",
    "train_model",
]

CHECKPOINT_FORMAT = "pved-train-checkpoint"


#: How :func:`train_model` can compute the gradient: by hand in numpy
#: (:mod:`pved.models.numpy_grad`, for every registered model; a subclass with its own
#: loss uses autograd) or with torch autograd for every model.
BACKENDS = ("numpy", "torch")


@contextmanager
def single_thread() -> Iterator[None]:
    """Run the block with one torch thread and one BLAS thread for numpy (runs are
    parallelised side by side, DESIGN.md "Principles"; a second BLAS thread on a busy
    core made the numpy step 6x slower, measured), restoring the settings afterwards."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        torch.set_num_threads(previous)


def _as_matrix(x: np.ndarray, side: str) -> np.ndarray:
    """Check a raw data array: 2-D, numeric, finite; returns it as float32 (M, D)."""
    arr = np.asarray(x)
    if arr.ndim != 2 or arr.shape[1] < 1:
        raise PvedError(f"x_{side} must be a 2-D array (M, D), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise PvedError(f"x_{side} must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float32, copy=False)
    bad = ~np.isfinite(arr)
    if bad.any():
        row = int(np.argwhere(bad)[0, 0])
        raise PvedError(
            f"x_{side} has {int(bad.sum())} NaN/inf value(s) (first in row {row}); "
            "clean the paired dataset"
        )
    return np.ascontiguousarray(arr)


def data_fingerprint(x_source: np.ndarray, x_target: np.ndarray) -> str:
    """Short hash of the paired data, so that a checkpoint is never resumed on other data."""
    digest = hashlib.sha256()
    for arr in (x_source, x_target):
        digest.update(str(arr.shape).encode())
        digest.update(np.ascontiguousarray(arr, dtype=np.float32).tobytes())
    return digest.hexdigest()[:16]


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random (train, validation) row indices; validation gets ``round(val_fraction·n)``
    rows, at least one when ``val_fraction > 0``, and training at least one."""
    perm = np.random.default_rng(seed).permutation(n)
    n_val = round(val_fraction * n)
    if val_fraction > 0:
        n_val = max(1, n_val)
    if n - n_val < 1:
        raise PvedError(
            f"only {n} paired rows: too few for a training split with val_fraction {val_fraction}"
        )
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


COLLAPSE_NATS = 0.01
"""Below this KL to the prior (nats per row) a shared posterior carries nothing."""


def shared_subspace_collapsed(parts: Mapping[str, float]) -> bool:
    """True when both shared posteriors, q(c|x_S) and q(c|x_T), sit on the prior N(0, I):
    their KLs to it (``kl_SS`` and ``kl_TT``, e.g. from :func:`evaluate_model` or a run's
    ``val/`` metrics without the prefix) are below :data:`COLLAPSE_NATS`. c then says
    nothing about either agent, and Eq. 10's reward, the KL between the two, is zero
    whatever the agents do. False for models without these terms (det-shared, Gupta)."""
    if "kl_SS" not in parts or "kl_TT" not in parts:
        return False
    return max(float(parts["kl_SS"]), float(parts["kl_TT"])) < COLLAPSE_NATS


@torch.no_grad()
def evaluate_model(
    model: SharedSpaceModel,
    x_source: np.ndarray | torch.Tensor,
    x_target: np.ndarray | torch.Tensor,
    batch_size: int = 4096,
    seed: int = 0,
) -> dict[str, float]:
    """Mean of every named loss part over a paired dataset (M, D_S), (M, D_T).

    The sampling noise comes from a generator seeded with ``seed``, so repeated
    evaluations of the same model on the same data agree exactly.
    """
    xs = torch.as_tensor(x_source, dtype=torch.float32)
    xt = torch.as_tensor(x_target, dtype=torch.float32)
    if xs.shape[0] != xt.shape[0] or xs.shape[0] < 1:
        raise PvedError(
            f"evaluation needs the same number (>= 1) of source and target rows, got "
            f"{xs.shape[0]} and {xt.shape[0]}"
        )
    was_training = model.training
    model.eval()
    generator = torch.Generator().manual_seed(seed)
    sums: dict[str, float] = {}
    for start in range(0, xs.shape[0], batch_size):
        stop = start + batch_size
        parts = model.loss(xs[start:stop], xt[start:stop], generator)
        n = min(batch_size, xs.shape[0] - start)
        for key, value in parts.items():
            sums[key] = sums.get(key, 0.0) + float(value) * n
    model.train(was_training)
    return {key: value / xs.shape[0] for key, value in sums.items()}


def train_model(
    name: str,
    x_source: np.ndarray,
    x_target: np.ndarray,
    config: ModelConfig | None = None,
    run: Run | None = None,
    *,
    state_dims: tuple[int, int],
    progress: bool = True,
    backend: str = "numpy",
) -> SharedSpaceModel:
    """Train model ``name`` on raw paired rows and return it (in eval mode).

    Args:
        name: a key of :data:`pved.models.MODELS`, e.g. ``"pved"``.
        x_source: (M, D_S) raw ``concat(s_S, a_S)`` rows.
        x_target: (M, D_T) raw ``concat(s_T, a_T)`` rows, row i paired with source row i.
        config: the model's config (its class's defaults when None); its training fields
            (lr, batch_size, epochs, val_fraction, seed, checkpoint_every, grad_clip) drive
            the loop.
        run: optional run directory: metrics, checkpoints, resume. ``run.start()`` is called
            here; writing ``result.json`` (``run.finish``) is left to the caller.
        state_dims: (state dim of x_S, state dim of x_T): the leading entries of each row
            that are the robot state; the rest are the action.
        progress: show a tqdm bar over epochs.
        backend: ``"numpy"`` computes the loss's gradient by hand
            (:mod:`pved.models.numpy_grad`: the same objective, noise and Adam update,
            2-2.4 times as fast; a model subclass with its own loss uses autograd);
            ``"torch"`` uses autograd for every model. Checkpoints are the same either
            way, so a run may resume under the other backend;
            ``model.metadata["train_backend"]`` says which one trained.

    Torch runs on one thread for the call (restored after) and its global RNG is seeded
    with ``config.seed`` (initialisation, sampling noise), so a run is reproducible.

    Raises:
        PvedError: bad shapes, NaN/inf in the data, a non-finite loss during training, or a
            checkpoint in ``run`` written for another model, layout or dataset.
    """
    cls = model_class(name)
    if config is None:
        config = cls.config_class()
    xs = _as_matrix(x_source, "source")
    xt = _as_matrix(x_target, "target")
    if xs.shape[0] != xt.shape[0]:
        raise PvedError(
            f"x_source has {xs.shape[0]} rows but x_target has {xt.shape[0]}; rows must be pairs"
        )
    if len(state_dims) != 2:
        raise PvedError(
            f"state_dims must be (source_state_dim, target_state_dim), got {state_dims}"
        )
    if backend not in BACKENDS:
        raise PvedError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    dims = ModelDims(int(xs.shape[1]), int(xt.shape[1]), int(state_dims[0]), int(state_dims[1]))
    with single_thread():
        return _train(name, xs, xt, dims, config, run, progress, backend)


def _train(
    name: str,
    xs: np.ndarray,
    xt: np.ndarray,
    dims: ModelDims,
    config: ModelConfig,
    run: Run | None,
    progress: bool,
    backend: str,
) -> SharedSpaceModel:
    fingerprint = data_fingerprint(xs, xt)
    train_idx, val_idx = split_indices(xs.shape[0], config.val_fraction, config.seed)
    xs_train, xt_train = torch.from_numpy(xs[train_idx]), torch.from_numpy(xt[train_idx])
    xs_val, xt_val = torch.from_numpy(xs[val_idx]), torch.from_numpy(xt[val_idx])

    torch.manual_seed(config.seed)  # initialisation and sampling noise
    model = build_model(name, dims, config)
    model.fit_standardization(xs_train, xt_train)
    # The fused kernel runs the update of all ~50 small tensors in one call: a third of
    # the foreach cost on CPU, and a tenth of the step time at batch 256.
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, fused=True)

    epoch, step = 0, 0
    if run is not None:
        run.start()
        state = run.latest_checkpoint()
        if state is not None:
            _check_checkpoint(state, name, dims, fingerprint, run)
            model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            torch.set_rng_state(state["torch_rng"])
            epoch, step = int(state["epoch"]), int(state["step"])
        # a run killed before its first checkpoint starts over
        run.drop_metrics_after(step if state is not None else -1)

    stepper: NumpyStep | None = None
    if backend == "numpy" and numpy_trainable(model):
        stepper = numpy_step(model, config.lr, config.grad_clip)
        stepper.load_from(optimizer)
        # standardised once: the statistics are fixed from here on
        fs_train, ft_train = stepper.features(xs_train, xt_train)
    model.metadata["train_backend"] = "numpy" if stepper is not None else "torch"

    def checkpoint() -> None:
        assert run is not None
        if stepper is not None:
            stepper.save_to(optimizer)
        run.save_checkpoint(
            step,
            {
                "format": CHECKPOINT_FORMAT,
                "model_name": name,
                "dims": dims.as_dict(),
                "data_fingerprint": fingerprint,
                "epoch": epoch,
                "step": step,
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
            },
        )

    n_train = xs_train.shape[0]
    bar = tqdm(
        total=config.epochs,
        initial=min(epoch, config.epochs),
        desc=f"train {name}",
        unit="epoch",
        disable=not progress,
    )
    try:
        while epoch < config.epochs:
            started = time.perf_counter()
            model.train()
            # A generator per epoch (not one running stream) makes the order after a
            # resume identical to an uninterrupted run's.
            order = torch.from_numpy(
                np.random.default_rng([config.seed, epoch]).permutation(n_train)
            )
            keys: list[str] = []
            sums = np.zeros(0)
            for start in range(0, n_train, config.batch_size):
                idx = order[start : start + config.batch_size]
                model.epochs_done = epoch + start / n_train
                if stepper is not None:
                    rows = idx.numpy()
                    keys = list(stepper.part_names)
                    values = stepper.step(fs_train[rows], ft_train[rows], model.epochs_done)
                else:
                    parts = model.loss(xs_train[idx], xt_train[idx])
                    keys = list(parts)
                    values = torch.stack([v.detach() for v in parts.values()]).double().numpy()
                    if math.isfinite(values[keys.index("total")]):
                        optimizer.zero_grad(set_to_none=True)
                        parts["total"].backward()
                        if config.grad_clip is not None:
                            torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
                        optimizer.step()
                if not math.isfinite(values[keys.index("total")]):
                    bad = [k for k, v in zip(keys, values, strict=True) if not math.isfinite(v)]
                    raise PvedError(
                        f"training {name} diverged: non-finite loss at epoch {epoch + 1}, "
                        f"step {step + 1} (non-finite parts: {', '.join(bad)}); try a "
                        "lower lr or check the data"
                    )
                step += 1
                sums = values * idx.shape[0] + (sums if sums.size else 0.0)
            epoch += 1
            train_means = dict(zip(keys, (sums / n_train).tolist(), strict=True))
            val_means = (
                evaluate_model(model, xs_val, xt_val, seed=config.seed)
                if xs_val.shape[0] > 0
                else {}
            )
            bar.update(1)
            bar.set_postfix(
                train=f"{train_means['total']:.3g}",
                val=f"{val_means.get('total', float('nan')):.3g}",
            )
            if run is not None:
                run.log(
                    step,
                    epoch=epoch,
                    epoch_seconds=time.perf_counter() - started,
                    **{f"train/{k}": v for k, v in train_means.items()},
                    **{f"val/{k}": v for k, v in val_means.items()},
                )
                if epoch % config.checkpoint_every == 0 or epoch == config.epochs:
                    checkpoint()
    finally:
        bar.close()
    model.eval()
    model.epochs_done = math.inf  # trained: any later loss is the paper's objective
    return model


def _check_checkpoint(
    state: dict[str, object], name: str, dims: ModelDims, fingerprint: str, run: Run
) -> None:
    where = run.checkpoint_dir
    if state.get("format") != CHECKPOINT_FORMAT:
        raise PvedError(f"{where}: newest checkpoint is not a model-training checkpoint")
    if state.get("model_name") != name:
        raise PvedError(
            f"{where}: checkpoint is for model {state.get('model_name')!r}, not {name!r}"
        )
    if state.get("dims") != dims.as_dict():
        raise PvedError(
            f"{where}: checkpoint dims {state.get('dims')} differ from the data's {dims.as_dict()}"
        )
    if state.get("data_fingerprint") != fingerprint:
        raise PvedError(
            f"{where}: checkpoint was trained on other paired data (fingerprint "
            f"{state.get('data_fingerprint')} vs {fingerprint}); use a fresh run directory"
        )
