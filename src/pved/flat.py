"""One flat float32 parameter vector: the buffer, Adam on it, and gradient clipping.

Small networks trained by hand-written numpy passes (PPO's actor-critic,
``pved.rl.ppo``; the shared-space models, ``pved.models.numpy_grad``) keep every
parameter as a view into one contiguous buffer, so that the optimiser, gradient clipping
and checkpoints act on one vector instead of dozens of small tensors: one set of vector
operations per step where torch's per-tensor optimisers issue a dozen per parameter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from pved.errors import PvedError

__all__ = ["FlatAdam", "FlatParams", "clip_grad_norm_np"]


class FlatParams:
    """Re-homes the given parameters into one contiguous float32 buffer.

    After construction the parameters *are* slices of :attr:`flat` (a torch
    tensor) whose numpy twin is :attr:`flat_np`; :attr:`grad_np` is a gradient buffer of
    the same layout. The optimiser, gradient clipping and checkpoints then act on one
    vector instead of a dozen small tensors.

    Attributes:
        flat: (P,) float32 tensor holding all parameters.
        flat_np: numpy view of ``flat``.
        grad_np: (P,) float32 gradient buffer.
        params_np / grads_np: per-parameter numpy views (parameter shapes), in the
            order given.
    """

    def __init__(self, params: Sequence[nn.Parameter]) -> None:
        params = list(params)
        total = sum(p.numel() for p in params)
        self.flat = torch.zeros(total, dtype=torch.float32)
        self.flat_np: np.ndarray = self.flat.numpy()
        self.grad_np = np.zeros(total, dtype=np.float32)
        self.params_np: list[np.ndarray] = []
        self.grads_np: list[np.ndarray] = []
        self.slices: list[slice] = []
        offset = 0
        for p in params:
            n = p.numel()
            view = self.flat[offset : offset + n].view_as(p)
            view.copy_(p.detach())
            p.data = view  # the parameter now lives in the flat buffer
            self.params_np.append(self.flat_np[offset : offset + n].reshape(tuple(p.shape)))
            self.grads_np.append(self.grad_np[offset : offset + n].reshape(tuple(p.shape)))
            self.slices.append(slice(offset, offset + n))
            offset += n
        self.params = params

    def grads_from_torch(self) -> None:
        """Copy autograd's ``.grad`` of every parameter into :attr:`grad_np`."""
        for p, g in zip(self.params, self.grads_np, strict=True):
            if p.grad is None:
                g.fill(0.0)
            else:
                g[...] = p.grad.numpy()


class FlatAdam:
    """Adam (Kingma & Ba) on a flat float32 vector, with torch.optim.Adam's exact update
    (bias-corrected step size, ε added to the bias-corrected √v). One set of vector ops
    per step instead of a dozen per-tensor ones."""

    def __init__(self, size: int, eps: float, betas: tuple[float, float] = (0.9, 0.999)) -> None:
        self.m = np.zeros(size, dtype=np.float32)
        self.v = np.zeros(size, dtype=np.float32)
        self.t = 0
        self.eps = float(eps)
        self.beta1, self.beta2 = betas
        self._tmp = np.zeros(size, dtype=np.float32)

    def step(self, params: np.ndarray, grads: np.ndarray, lr: float) -> None:
        """params, grads: (P,) float32; params updated in place."""
        self.t += 1
        b1, b2, tmp = self.beta1, self.beta2, self._tmp
        self.m += (grads - self.m) * np.float32(1.0 - b1)  # torch: exp_avg.lerp_(grad, 1-b1)
        self.v *= np.float32(b2)
        np.multiply(grads, grads, out=tmp)
        tmp *= np.float32(1.0 - b2)
        self.v += tmp
        bias1 = 1.0 - b1**self.t
        bias2_sqrt = math.sqrt(1.0 - b2**self.t)
        np.sqrt(self.v, out=tmp)
        tmp /= np.float32(bias2_sqrt)
        tmp += np.float32(self.eps)
        np.divide(self.m, tmp, out=tmp)
        tmp *= np.float32(-lr / bias1)
        params += tmp

    def state_dict(self) -> dict[str, Any]:
        return {
            "m": torch.from_numpy(self.m.copy()),
            "v": torch.from_numpy(self.v.copy()),
            "t": self.t,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        m, v = state["m"].numpy(), state["v"].numpy()
        if m.shape != self.m.shape or v.shape != self.v.shape:
            raise PvedError(
                f"optimizer state has {m.shape[0]} entries, the networks {self.m.shape[0]}"
            )
        self.m[...] = m
        self.v[...] = v
        self.t = int(state["t"])


def clip_grad_norm_np(grads: np.ndarray, max_norm: float) -> float:
    """Scale ``grads`` (P,) in place to global norm ≤ max_norm (torch's rule, including
    its 1e-6); returns the norm before clipping."""
    norm = math.sqrt(float(np.dot(grads, grads)))
    coef = max_norm / (norm + 1e-6)
    if coef < 1.0:
        grads *= np.float32(coef)
    return norm
