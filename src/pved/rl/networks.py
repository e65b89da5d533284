"""Actor-critic networks and a numpy forward/backward.

The networks are ordinary ``torch.nn`` modules (so that they save as state dicts, load
with ``weights_only=True`` and can be used in torch code by anyone), but PPO trains them
through a hand-written numpy forward and backward pass over the *same memory*: every
parameter is a view into one contiguous float32 buffer, and ``pved.flat.FlatParams``
exposes that buffer and its per-tensor views to numpy.

Why by hand: PPO's networks here are tiny (two or three layers of 64 units) and its
minibatches small (64 rows). At that size torch's per-operator dispatch and autograd
bookkeeping cost far more than the arithmetic: on the development machine one
minibatch-64 update of 64-64 networks took ~1200 µs with autograd, torch.distributions
and Adam, ~850 µs with a hand-written log-density and fused Adam, and ~160 µs as about
sixty numpy calls. The backward pass is checked against torch autograd in
``tests/test_ppo.py``, and ``PPOConfig(backend="torch")`` trains with autograd instead.

Shapes: B is a batch of rows, ``in``/``out`` a layer's widths. A torch ``nn.Linear``
weight is ``(out, in)`` and computes ``y = x @ W.T + b``; the numpy code uses the same
views, so ``W.T`` is a free transposed view handed to BLAS.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Literal, cast

import numpy as np
import torch
from torch import nn

from pved.errors import PvedError

Activation = Literal["tanh", "relu", "leaky_relu"]
ACTIVATIONS: tuple[str, ...] = ("tanh", "relu", "leaky_relu")
LEAKY_SLOPE = 0.01
LOG_2PI = math.log(2.0 * math.pi)


def check_activation(name: str) -> Activation:
    """``name`` if it is a supported activation, else :class:`PvedError`."""
    if name not in ACTIVATIONS:
        raise PvedError(f"unknown activation {name!r}; choose one of {', '.join(ACTIVATIONS)}")
    return cast(Activation, name)


def _torch_activation(name: Activation) -> nn.Module:
    if name == "tanh":
        return nn.Tanh()
    if name == "relu":
        return nn.ReLU()
    return nn.LeakyReLU(LEAKY_SLOPE)


class MLP(nn.Module):
    """``in → hidden[0] → … → hidden[-1] → out`` with ``activation`` after every hidden
    layer and a linear output.

    Args:
        in_dim: input width.
        hidden_sizes: widths of the hidden layers (the paper's policies: (64, 64, 64)).
        out_dim: output width.
        activation: ``"tanh"``, ``"relu"`` or ``"leaky_relu"``.
    """

    def __init__(
        self, in_dim: int, hidden_sizes: Sequence[int], out_dim: int, activation: str
    ) -> None:
        super().__init__()
        self.activation: Activation = check_activation(activation)
        widths = [int(in_dim), *(int(h) for h in hidden_sizes), int(out_dim)]
        if any(w <= 0 for w in widths):
            raise PvedError(f"layer widths must be positive, got {widths}")
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(widths))
        self._act = _torch_activation(self.activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, in) → (B, out)."""
        for layer in self.layers[:-1]:
            x = self._act(layer(x))
        out: torch.Tensor = self.layers[-1](x)
        return out

    def init_orthogonal(self, out_gain: float, generator: torch.Generator) -> None:
        """Orthogonal weights (gain √2 on hidden layers, ``out_gain`` on the output) and
        zero biases: the initialisation of OpenAI Baselines, Stable-Baselines3 and CleanRL,
        under which PPO's published MuJoCo results were obtained."""
        for i, layer in enumerate(self.layers):
            lin = cast(nn.Linear, layer)
            gain = out_gain if i == len(self.layers) - 1 else math.sqrt(2.0)
            nn.init.orthogonal_(lin.weight, gain=gain, generator=generator)
            nn.init.zeros_(lin.bias)


class ActorCritic(nn.Module):
    """Gaussian actor with a state-independent log standard deviation, and a critic.

    The actor maps an (already normalised) observation to the action mean; the policy is
    ``N(mean(s), diag(exp(log_std))²)``. The critic maps it to V(s).
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int] = (64, 64, 64),
        activation: str = "relu",
        init_log_std: float = 0.0,
    ) -> None:
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.act_dim = int(act_dim)
        self.hidden_sizes = tuple(int(h) for h in hidden_sizes)
        self.activation = check_activation(activation)
        self.actor = MLP(obs_dim, self.hidden_sizes, act_dim, activation)
        self.critic = MLP(obs_dim, self.hidden_sizes, 1, activation)
        self.log_std = nn.Parameter(torch.full((self.act_dim,), float(init_log_std)))

    def init_weights(self, seed: int) -> None:
        """Seeded orthogonal init; the actor's output gain 0.01 starts the policy near a
        zero mean (so early actions are the exploration noise), the critic's is 1."""
        gen = torch.Generator().manual_seed(int(seed))
        self.actor.init_orthogonal(0.01, gen)
        self.critic.init_orthogonal(1.0, gen)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """obs: (B, obs_dim) normalised → (action mean (B, act_dim), value (B,))."""
        return self.actor(obs), self.critic(obs).squeeze(-1)

    def ordered_parameters(self) -> list[nn.Parameter]:
        """Actor layers (W, b, ...), critic layers, then log_std: the layout of
        :class:`pved.flat.FlatParams` (``parameters()`` would put log_std first)."""
        return [*self.actor.parameters(), *self.critic.parameters(), self.log_std]


# ----------------------------------------------------------------------------------------
# One contiguous buffer under all parameters
# ----------------------------------------------------------------------------------------


def actor_critic_views(
    views: Sequence[np.ndarray], net: ActorCritic
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """Split per-parameter arrays in ``net.ordered_parameters()`` order (e.g.
    :attr:`pved.flat.FlatParams.params_np` or ``grads_np``) into actor layers
    [(W, b), ...], critic layers and log_std."""
    n_actor = 2 * len(net.actor.layers)
    n_critic = 2 * len(net.critic.layers)
    if len(views) != n_actor + n_critic + 1:
        raise PvedError("parameter views do not match the ActorCritic they were built from")
    views = list(views)
    return _pairs(views[:n_actor]), _pairs(views[n_actor : n_actor + n_critic]), views[-1]


def _pairs(views: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(views[i], views[i + 1]) for i in range(0, len(views), 2)]


def module_views(net: nn.Module) -> list[tuple[np.ndarray, np.ndarray]]:
    """Numpy views (W (out, in), b (out,)) of an :class:`MLP`'s layers, sharing memory
    with its parameters (CPU float32)."""
    layers = cast(nn.ModuleList, net.layers)
    out = []
    for layer in layers:
        lin = cast(nn.Linear, layer)
        out.append((lin.weight.detach().numpy(), lin.bias.detach().numpy()))
    return out


# ----------------------------------------------------------------------------------------
# numpy forward / backward of an MLP
# ----------------------------------------------------------------------------------------


def mlp_forward_np(
    x: np.ndarray, layers: Sequence[tuple[np.ndarray, np.ndarray]], activation: str
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Forward pass.

    Args:
        x: (B, in) float32.
        layers: [(W (out, in), b (out,)), ...].
        activation: the hidden activation.

    Returns:
        out: (B, out_dim); hidden: the post-activation output of every hidden layer,
        each (B, width), kept for :func:`mlp_backward_np`.
    """
    hidden: list[np.ndarray] = []
    h = x
    for W, b in layers[:-1]:
        z = h @ W.T
        z += b
        if activation == "tanh":
            np.tanh(z, out=z)
        elif activation == "relu":
            np.maximum(z, 0.0, out=z)
        else:  # leaky_relu: max(z, slope·z) for slope < 1
            np.maximum(z, z * LEAKY_SLOPE, out=z)
        hidden.append(z)
        h = z
    W, b = layers[-1]
    out = h @ W.T
    out += b
    return out, hidden


def mlp_backward_np(
    x: np.ndarray,
    hidden: Sequence[np.ndarray],
    d_out: np.ndarray,
    layers: Sequence[tuple[np.ndarray, np.ndarray]],
    grads: Sequence[tuple[np.ndarray, np.ndarray]],
    activation: str,
) -> None:
    """Backward pass of :func:`mlp_forward_np`, writing parameter gradients in place.

    Args:
        x: (B, in) the forward input; hidden: its cached hidden outputs.
        d_out: (B, out_dim) dLoss/d(output).
        layers: the weights used in the forward pass.
        grads: [(dW (out, in), db (out,)), ...] buffers to overwrite.
        activation: the hidden activation (its derivative is read off the cached output:
            tanh' = 1 − h², relu' = [h > 0], leaky' = 1 if h > 0 else slope).
    """
    delta = d_out
    for k in range(len(layers) - 1, -1, -1):
        inp = hidden[k - 1] if k > 0 else x
        gW, gb = grads[k]
        np.matmul(delta.T, inp, out=gW)
        np.sum(delta, axis=0, out=gb)
        if k == 0:
            break
        delta = delta @ layers[k][0]
        h = hidden[k - 1]
        if activation == "tanh":
            delta *= 1.0 - h * h
        elif activation == "relu":
            delta *= h > 0.0
        else:
            delta *= np.where(h > 0.0, np.float32(1.0), np.float32(LEAKY_SLOPE))


# ----------------------------------------------------------------------------------------
# Observation normaliser
# ----------------------------------------------------------------------------------------


class RunningMeanStd:
    """Running mean and variance of a stream of batches (Chan et al.'s parallel update),
    in float64; the statistics PPO normalises observations (and scales rewards) with.

    ``count`` starts at a tiny epsilon, as in OpenAI Baselines, so the first update is
    well defined.
    """

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-4) -> None:
        self.mean = np.zeros(shape, dtype=np.float64)
        self.var = np.ones(shape, dtype=np.float64)
        self.count = float(epsilon)

    def update(self, batch: np.ndarray) -> None:
        """batch: (B, *shape)."""
        b_mean = batch.mean(axis=0)
        b_var = batch.var(axis=0)
        b_count = batch.shape[0]
        delta = b_mean - self.mean
        total = self.count + b_count
        self.mean = self.mean + delta * (b_count / total)
        m2 = (
            self.var * self.count + b_var * b_count + delta * delta * (self.count * b_count / total)
        )
        self.var = m2 / total
        self.count = total

    def state_dict(self) -> dict[str, torch.Tensor | float]:
        return {
            "mean": torch.from_numpy(self.mean.copy()),
            "var": torch.from_numpy(self.var.copy()),
            "count": float(self.count),
        }

    def load_state_dict(self, state: dict[str, torch.Tensor | float]) -> None:
        mean = np.asarray(cast(torch.Tensor, state["mean"]).numpy(), dtype=np.float64)
        var = np.asarray(cast(torch.Tensor, state["var"]).numpy(), dtype=np.float64)
        if mean.shape != self.mean.shape or var.shape != self.var.shape:
            raise PvedError(
                f"normaliser shape {mean.shape} does not match the expected {self.mean.shape}"
            )
        self.mean = mean.copy()
        self.var = var.copy()
        self.count = float(state["count"])


class ObsNormalizer:
    """``clip((obs − mean) / sqrt(var + eps), −clip, clip)`` as float32, with running
    statistics (identity when disabled). Saved with the policy so that every later stage
    scales observations exactly as training did."""

    def __init__(self, obs_dim: int, enabled: bool, clip: float = 10.0, eps: float = 1e-8) -> None:
        self.enabled = bool(enabled)
        self.clip = float(clip)
        self.eps = float(eps)
        self.rms = RunningMeanStd((int(obs_dim),))
        self._refresh()

    def _refresh(self) -> None:
        self._mean32 = self.rms.mean.astype(np.float32)
        self._inv_std32 = (1.0 / np.sqrt(self.rms.var + self.eps)).astype(np.float32)

    def update(self, obs: np.ndarray) -> None:
        """obs: (B, obs_dim) raw observations."""
        if self.enabled:
            self.rms.update(obs)
            self._refresh()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """obs: (B, obs_dim) raw → (B, obs_dim) float32 normalised."""
        x = np.asarray(obs, dtype=np.float32)
        if not self.enabled:
            return x.copy() if x is obs else x
        x = (x - self._mean32) * self._inv_std32
        np.clip(x, -self.clip, self.clip, out=x)
        return x

    def state_dict(self) -> dict[str, object]:
        return {
            "enabled": self.enabled,
            "clip": self.clip,
            "eps": self.eps,
            **self.rms.state_dict(),
        }

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.enabled = bool(state["enabled"])
        self.clip = float(cast(float, state["clip"]))
        self.eps = float(cast(float, state["eps"]))
        self.rms.load_state_dict(
            {k: cast("torch.Tensor | float", state[k]) for k in ("mean", "var", "count")}
        )
        self._refresh()
