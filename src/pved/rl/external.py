"""Policies from where users have them: one loader for every verb.

:func:`load_policy_file` reads pved's own policy file (``Policy.save``) or a
Stable-Baselines3 ``.zip`` (``model.save``), the latter with SB3's own loader behind an
adapter that has pved's :class:`~pved.rl.policy.Actor` interface. SB3 is an optional
extra (``pip install pved[sb3]``) imported only when such a file is given, so
``import pved`` never needs it. docs/decisions/sources.md says how SB3's
policies map onto pved's.

An SB3 file is a zip holding a ``data`` JSON entry and a ``policy.pth``; loading it
unpickles the classes it names (SB3's format), so, unlike pved's own files, it may run
code: load only files you trust.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.rl.policy import Actor, load_policy

#: SB3 policy classes by the module that defines them (read from the zip's JSON, before
#: anything is unpickled) -> the algorithm class whose ``load`` rebuilds them. A2C's
#: policy is PPO's class and DDPG's is TD3's, so those load as their sibling.
_SB3_ALGORITHMS = {
    "stable_baselines3.common.policies": "PPO",
    "stable_baselines3.sac.policies": "SAC",
    "stable_baselines3.td3.policies": "TD3",
}
SB3_HINT = "pip install pved[sb3]"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__)[:160]


def _sb3_data(path: Path) -> dict[str, Any] | None:
    """The ``data`` JSON of an SB3 zip at ``path``; None when the file is not one."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            if not {"data", "policy.pth"} <= names:
                return None
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class SB3Policy:
    """An SB3 model's policy seen through pved's :class:`~pved.rl.policy.Actor`.

    ``act(deterministic=True)`` is SB3's own deterministic prediction (the Gaussian's
    mean clipped to the action bounds, as pved's :class:`~pved.rl.policy.Policy`; a
    squashed policy's tanh-mean). A sampled action of a diagonal-Gaussian policy (PPO,
    A2C) is the mean plus the policy's std times noise drawn from ``rng``, then clipped, so
    a seeded rollout repeats as pved's own policies' do; other policies sample with SB3's
    own sampler under a torch seed drawn from ``rng``.

    Attributes:
        model: the SB3 algorithm object (on CPU).
        path: the file it came from.
        metadata: plain data about it (algorithm, SB3 version, timesteps trained).
    """

    def __init__(self, model: Any, path: Path) -> None:
        obs_space, act_space = model.observation_space, model.action_space
        if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
            raise PvedError(f"SB3 policy {path} observes {obs_space}; pved needs a flat Box")
        if not isinstance(act_space, gym.spaces.Box) or len(act_space.shape) != 1:
            raise PvedError(f"SB3 policy {path} acts in {act_space}; pved needs a flat Box")
        self.model = model
        self.path = path
        self.observation_space = obs_space
        self.action_space = act_space
        self.action_low = np.asarray(act_space.low, dtype=np.float64)
        self.action_high = np.asarray(act_space.high, dtype=np.float64)
        import stable_baselines3 as sb3

        self.metadata: dict[str, Any] = {
            "format": "stable-baselines3",
            "algorithm": type(model).__name__,
            "sb3_version": sb3.__version__,
            "training_steps": int(getattr(model, "num_timesteps", 0)),
            "seed": getattr(model, "seed", None),
        }
        # the noise of sampled actions when the caller gives no rng, as Policy's own
        self._rng = np.random.default_rng(int(self.metadata["seed"] or 0))

    @property
    def obs_dim(self) -> int:
        return int(self.observation_space.shape[0])

    @property
    def act_dim(self) -> int:
        return int(self.action_space.shape[0])

    def act(
        self,
        obs: np.ndarray,
        deterministic: bool = False,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Actions (N, act_dim) float64 for raw observations (N, obs_dim)."""
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise PvedError(
                f"SB3 policy {self.path} expects observations of shape (N, {self.obs_dim}), "
                f"got {obs.shape}"
            )
        policy = self.model.policy
        gen = self._rng if rng is None else rng
        if deterministic:
            action, _ = policy.predict(obs, deterministic=True)
            return np.asarray(action, dtype=np.float64).reshape(len(obs), self.act_dim)
        from stable_baselines3.common.distributions import DiagGaussianDistribution

        with torch.no_grad():
            tensor, _ = policy.obs_to_tensor(obs)
            dist = policy.get_distribution(tensor) if hasattr(policy, "get_distribution") else None
            if isinstance(dist, DiagGaussianDistribution) and not policy.squash_output:
                mean = dist.distribution.mean.double().numpy()
                std = dist.distribution.stddev.double().numpy()
                sample = mean + std * gen.standard_normal(mean.shape)
                return np.asarray(np.clip(sample, self.action_low, self.action_high))
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(gen.integers(2**62)))
            action, _ = policy.predict(obs, deterministic=False)
        return np.asarray(action, dtype=np.float64).reshape(len(obs), self.act_dim)


def load_sb3_policy(path: Path | str) -> SB3Policy:
    """An SB3 ``.zip`` loaded with SB3's own loader, as an :class:`SB3Policy`."""
    path = Path(path)
    data = _sb3_data(path)
    if data is None:
        raise PvedError(f"{path} is not a Stable-Baselines3 model file (a zip with 'data')")
    policy_class = data.get("policy_class")
    module = policy_class.get("__module__") if isinstance(policy_class, dict) else None
    algorithm = _SB3_ALGORITHMS.get(str(module))
    if algorithm is None:
        raise PvedError(
            f"SB3 policy {path} is a {module} policy; pved reads PPO, A2C, SAC, TD3 and "
            "DDPG policies on Box spaces"
        )
    try:
        import stable_baselines3 as sb3
    except ImportError:
        raise PvedError(f"{path} is a Stable-Baselines3 model; to load it: {SB3_HINT}") from None
    # schedules are only needed to train on: given as constants, SB3 need not unpickle them
    constants = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    try:
        model = getattr(sb3, algorithm).load(path, device="cpu", custom_objects=constants)
    except Exception as exc:  # SB3 raises many types for a bad file
        raise PvedError(f"cannot load SB3 model {path}: {_first_line(exc)}") from None
    return SB3Policy(model, path)


def check_policy_env(policy: Actor, path: Path | str, env_name: str, env: BatchedEnv) -> None:
    """Refuse, in one line, a policy made for another agent: its observation and action
    dims against ``env``'s and, for an SB3 policy, its action bounds too (SB3 clips to
    the bounds it was trained with)."""
    obs_dim = int(env.single_observation_space.shape[0])
    act_dim = int(env.single_action_space.shape[0])
    if policy.obs_dim != obs_dim:
        raise PvedError(
            f"policy {path} and {env_name} do not match: the policy observes "
            f"{policy.obs_dim} dims, the env {obs_dim}"
        )
    if policy.act_dim != act_dim:
        raise PvedError(
            f"policy {path} and {env_name} do not match: the policy acts in "
            f"{policy.act_dim} dims, the env in {act_dim}"
        )
    if isinstance(policy, SB3Policy):
        low = np.asarray(env.single_action_space.low, dtype=np.float64)
        high = np.asarray(env.single_action_space.high, dtype=np.float64)
        if not (np.allclose(policy.action_low, low) and np.allclose(policy.action_high, high)):
            raise PvedError(
                f"SB3 policy {path} acts within [{policy.action_low.min():g}, "
                f"{policy.action_high.max():g}], {env_name}'s actions within "
                f"[{low.min():g}, {high.max():g}]"
            )


def load_policy_file(
    path: Path | str, *, env: BatchedEnv | None = None, env_name: str | None = None
) -> Actor:
    """The policy in ``path``, whatever made it: pved (``Policy.save``) or SB3 (a
    ``.zip`` from ``model.save``). With ``env``, a policy made for another agent is
    refused in one line (:func:`check_policy_env`). Every failure is a
    :class:`PvedError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise PvedError(f"policy not found: {path}")
    policy: Actor = load_sb3_policy(path) if _sb3_data(path) is not None else load_policy(path)
    if env is not None:
        check_policy_env(policy, path, env_name or "the env", env)
    return policy
