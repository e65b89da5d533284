"""A trained policy: actor, critic and the observation normaliser it was trained with.

Saved files hold state dicts and plain metadata only, so they load with
``torch.load(weights_only=True)`` (DESIGN.md: weights load without executing code)::

    {"format": "pved-policy", "format_version": 1,
     "actor_critic": <ActorCritic state dict>, "obs_normalizer": {...},
     "action_low": (act_dim,), "action_high": (act_dim,),
     "metadata": {"obs_dim", "act_dim", "hidden_sizes", "activation", "env_id",
                  "training_steps", "seed", "pved_version", ...}}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
import torch

from pved import __version__
from pved.errors import PvedError
from pved.rl.networks import LOG_2PI, ActorCritic, ObsNormalizer, mlp_forward_np, module_views
from pved.runs import atomic_torch_save, safe_torch_load, to_jsonable

POLICY_FORMAT = "pved-policy"
POLICY_FORMAT_VERSION = 1


class Actor(Protocol):
    """What rolling a policy out needs (pairing, source banks, evaluation): pved's
    :class:`Policy`, or an adapter over another library's (``pved.rl.external``)."""

    @property
    def obs_dim(self) -> int: ...

    @property
    def act_dim(self) -> int: ...

    def act(
        self,
        obs: np.ndarray,
        deterministic: bool = False,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray: ...


class Policy:
    """Gaussian policy ``a ~ N(mean(norm(s)), diag(exp(log_std))²)`` with its critic.

    Args:
        net: the actor-critic (parameters on CPU, float32).
        obs_normalizer: the normaliser applied to raw observations before the networks.
        action_low / action_high: (act_dim,) bounds that :meth:`act` clips actions to.
        metadata: plain data describing the policy (see module docstring).
    """

    def __init__(
        self,
        net: ActorCritic,
        obs_normalizer: ObsNormalizer,
        action_low: np.ndarray,
        action_high: np.ndarray,
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        self.net = net
        self.obs_normalizer = obs_normalizer
        self.action_low = np.asarray(action_low, dtype=np.float64).reshape(net.act_dim)
        self.action_high = np.asarray(action_high, dtype=np.float64).reshape(net.act_dim)
        self.metadata: dict[str, Any] = dict(metadata or {})
        # numpy views sharing memory with the torch parameters: the forward pass used
        # by ``act`` is the same numpy code PPO's rollouts use.
        self._actor = module_views(net.actor)
        self._critic = module_views(net.critic)
        self._log_std = net.log_std.detach().numpy()
        self._rng = np.random.default_rng(int(self.metadata.get("seed", 0) or 0))

    @property
    def obs_dim(self) -> int:
        return self.net.obs_dim

    @property
    def act_dim(self) -> int:
        return self.net.act_dim

    def _check_obs(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise PvedError(
                f"policy expects observations of shape (N, {self.obs_dim}), got {obs.shape}"
            )
        return obs

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """obs: (N, obs_dim) raw → (N, obs_dim) float32 as the networks see it."""
        return self.obs_normalizer(self._check_obs(obs))

    def mean_action(self, obs: np.ndarray) -> np.ndarray:
        """obs: (N, obs_dim) raw → unclipped action means (N, act_dim) float32."""
        mean, _ = mlp_forward_np(self.normalize(obs), self._actor, self.net.activation)
        return mean

    def act(
        self,
        obs: np.ndarray,
        deterministic: bool = False,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Actions for a batch of raw observations, clipped to the action bounds.

        Args:
            obs: (N, obs_dim).
            deterministic: the mean action instead of a sample.
            rng: source of the exploration noise; by default the policy's own generator
                (seeded from its training seed).

        Returns:
            (N, act_dim) float64.
        """
        mean = self.mean_action(obs).astype(np.float64)
        if not deterministic:
            gen = self._rng if rng is None else rng
            mean += np.exp(self._log_std.astype(np.float64)) * gen.standard_normal(mean.shape)
        return np.clip(mean, self.action_low, self.action_high)

    def value(self, obs: np.ndarray) -> np.ndarray:
        """obs: (N, obs_dim) raw → V(s) (N,) float32."""
        v, _ = mlp_forward_np(self.normalize(obs), self._critic, self.net.activation)
        return v[:, 0]

    def log_prob(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """log π(a|s) of unclipped actions (N, act_dim) → (N,) float64."""
        mean = self.mean_action(obs).astype(np.float64)
        log_std = self._log_std.astype(np.float64)
        z = (np.asarray(actions, dtype=np.float64) - mean) * np.exp(-log_std)
        return np.asarray(-0.5 * (z * z).sum(axis=1) - log_std.sum() - 0.5 * self.act_dim * LOG_2PI)

    # -- files -------------------------------------------------------------------------
    def state(self, metadata: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The saved form (tensors and plain data only)."""
        meta = {**self.metadata, **dict(metadata or {})}
        meta.update(
            obs_dim=self.obs_dim,
            act_dim=self.act_dim,
            hidden_sizes=list(self.net.hidden_sizes),
            activation=self.net.activation,
        )
        meta.setdefault("pved_version", __version__)
        plain = to_jsonable(meta)
        try:
            json.dumps(plain)
        except (TypeError, ValueError) as exc:
            raise PvedError(f"policy metadata must be plain JSON data: {exc}") from None
        return {
            "format": POLICY_FORMAT,
            "format_version": POLICY_FORMAT_VERSION,
            "actor_critic": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
            "obs_normalizer": self.obs_normalizer.state_dict(),
            "action_low": torch.from_numpy(self.action_low.copy()),
            "action_high": torch.from_numpy(self.action_high.copy()),
            "metadata": plain,
        }

    def save(self, path: Path | str, metadata: Mapping[str, Any] | None = None) -> Path:
        """Atomically write the policy to ``path``; ``metadata`` is merged over the
        policy's own (env id, training steps, seed, ...). Returns the path."""
        path = Path(path)
        atomic_torch_save(path, self.state(metadata))
        return path


def policy_from_state(state: Mapping[str, Any], source: str = "policy state") -> Policy:
    """Rebuild a :class:`Policy` from :meth:`Policy.state`, checking every part."""
    if not isinstance(state, Mapping) or state.get("format") != POLICY_FORMAT:
        raise PvedError(f"{source} is not a pved policy file (no 'format: {POLICY_FORMAT}')")
    if state.get("format_version") != POLICY_FORMAT_VERSION:
        raise PvedError(
            f"{source} has policy format version {state.get('format_version')!r}; "
            f"this pved reads version {POLICY_FORMAT_VERSION}"
        )
    missing = [
        k
        for k in ("actor_critic", "obs_normalizer", "action_low", "action_high", "metadata")
        if k not in state
    ]
    if missing:
        raise PvedError(f"{source} lacks {', '.join(missing)}")
    meta = dict(state["metadata"])
    try:
        net = ActorCritic(
            int(meta["obs_dim"]),
            int(meta["act_dim"]),
            tuple(int(h) for h in meta["hidden_sizes"]),
            str(meta["activation"]),
        )
        net.load_state_dict(state["actor_critic"])
        norm = ObsNormalizer(int(meta["obs_dim"]), enabled=True)
        norm.load_state_dict(dict(state["obs_normalizer"]))
        low = cast(torch.Tensor, state["action_low"]).numpy()
        high = cast(torch.Tensor, state["action_high"]).numpy()
        if low.shape != (net.act_dim,) or high.shape != (net.act_dim,):
            raise PvedError(f"action bounds have shape {low.shape}, expected ({net.act_dim},)")
    except PvedError as exc:
        raise PvedError(f"{source}: {exc}") from None
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PvedError(f"{source} is not a valid pved policy ({first[:160]})") from None
    return Policy(net, norm, low, high, meta)


def load_policy(path: Path | str) -> Policy:
    """Load a policy written by :meth:`Policy.save` (no code is executed); a missing,
    corrupt or foreign file raises :class:`PvedError` naming it."""
    path = Path(path)
    return policy_from_state(safe_torch_load(path), str(path))
