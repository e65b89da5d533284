"""Proximal Policy Optimisation (Schulman et al. 2017) over a :class:`BatchedEnv`.

Every policy in pved is trained here (paper III.G): the source and target policies on
the training tasks, the source policies on the target tasks, and the target agent's
policy with the PVED shaping term (Eq. 10), which arrives as an ordinary reward from a
wrapping ``BatchedEnv`` (deferred to the rollout's end where the wrapper offers it).

Read top to bottom:

1. :class:`PPOConfig`: every hyper-parameter, frozen.
2. :func:`train_ppo`: rollouts with ONE policy forward for all N envs per step,
   advantage estimation (:func:`pved.rl.losses.compute_gae`), epochs of shuffled
   minibatch updates on the clipped loss (:func:`pved.rl.losses.ppo_loss_grad`, or
   :func:`~pved.rl.losses.ppo_loss` in torch), logging, checkpoints, resume, evaluation.

Conventions. T = ``steps_per_env``, N = ``num_envs``, B = a minibatch, A = action dim,
O = observation dim. Episodes that end by truncation (time limit) are bootstrapped with
V of ``info["final_obs"]``; episodes that terminate are not.

One module past 600 lines on purpose: PPO's loop is one idea, its config, trainer state,
checkpoints and resume sharing one set of buffers and one order of operations; split,
each part would have to know the others' internals.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import torch
from tqdm import tqdm

from pved import __version__
from pved.checks import check_int, check_number, check_seed
from pved.envs.base import BatchedEnv
from pved.errors import OptionError, PvedError
from pved.flat import FlatAdam, FlatParams, clip_grad_norm_np
from pved.rl.guide import GUIDE_CONTEXT, GUIDE_GRAD_RATIO, GUIDE_MASK, ActionGuide, RewardGate
from pved.rl.losses import compute_gae, gaussian_log_prob_np, ppo_loss, ppo_loss_grad
from pved.rl.networks import (
    ActorCritic,
    ObsNormalizer,
    RunningMeanStd,
    actor_critic_views,
    check_activation,
    mlp_backward_np,
    mlp_forward_np,
)
from pved.rl.policy import Policy
from pved.runs import Run, to_jsonable

CHECKPOINT_FORMAT = "pved-ppo-checkpoint"
BACKENDS = ("numpy", "torch")


# ========================================================================================
# 1. Configuration
# ========================================================================================


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters. The defaults are the paper's networks (III.G: three hidden
    layers of 64 with ReLU) with CleanRL's validated MuJoCo settings for the rest.

    Attributes:
        total_steps: env steps to train for (rounded up to whole updates).
        num_envs: N, copies stepped together (must equal the env's ``num_envs``).
        steps_per_env: T, rollout length per env; one update sees N·T transitions.
        epochs: passes over each rollout.
        minibatch_size: rows per gradient step (must divide N·T).
        lr: Adam learning rate; ``anneal_lr`` decays it linearly to 0 over training.
        adam_eps: Adam's epsilon (1e-5 as in Baselines/SB3/CleanRL, not torch's 1e-8).
        gamma, gae_lambda: discount and GAE λ.
        clip: ε of the clipped surrogate.
        clip_value: if set, the value loss is max(unclipped, clipped) with the value
            change clipped to ±clip_value (Baselines' PPO2); None: plain squared error.
        ent_coef, vf_coef: weights of the entropy bonus and of the value loss
            ``½·mean((V − R)²)``.
        max_grad_norm: global gradient-norm clip.
        target_kl: stop the update's remaining minibatches once a minibatch's approx-KL
            exceeds 1.5·target_kl (Stable-Baselines3's rule); None disables.
        normalize_advantage: standardise advantages per minibatch.
        hidden_sizes, activation: actor and critic widths and hidden activation.
        init_log_std: initial log standard deviation of the Gaussian policy.
        normalize_obs, obs_clip: running mean/var observation normalisation (saved with
            the policy) and the clip applied after it.
        normalize_reward, reward_clip: scale rewards by the running std of the
            discounted return (as Gymnasium's NormalizeReward), then clip; a shaped
            env's term is scaled by the same std (of the shaped return) and not clipped.
        seed: seeds the networks' initialisation, the action noise, the minibatch
            shuffles and the env's reset.
        checkpoint_every: env steps between checkpoints (0: none).
        eval_every: env steps between ``eval_fn`` calls (0: only at the end).
        backend: ``"numpy"`` (hand-written backward, fast) or ``"torch"`` (autograd);
            both compute the same update.
    """

    total_steps: int = 1_000_000
    num_envs: int = 16
    steps_per_env: int = 128
    epochs: int = 10
    minibatch_size: int = 64
    lr: float = 3e-4
    anneal_lr: bool = True
    adam_eps: float = 1e-5
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    clip_value: float | None = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    normalize_advantage: bool = True
    hidden_sizes: tuple[int, ...] = (64, 64, 64)
    activation: str = "relu"
    init_log_std: float = 0.0
    normalize_obs: bool = True
    obs_clip: float = 10.0
    normalize_reward: bool = True
    reward_clip: float = 10.0
    seed: int = 0
    checkpoint_every: int = 100_000
    eval_every: int = 0
    backend: str = "numpy"

    def __post_init__(self) -> None:
        # accept lists (from JSON) for hidden sizes, keeping the dataclass hashable
        if not isinstance(self.hidden_sizes, list | tuple) or not self.hidden_sizes:
            raise OptionError("hidden_sizes", self.hidden_sizes, "a non-empty list of widths")
        widths = tuple(check_int("hidden_sizes", h, low=1) for h in self.hidden_sizes)
        object.__setattr__(self, "hidden_sizes", widths)
        # each value checked by type and range here, the one place a PPO config is made
        # from a user's options (docs/decisions.md, "Bad input and kills")
        for name in ("total_steps", "num_envs", "steps_per_env", "epochs", "minibatch_size"):
            check_int(name, getattr(self, name), low=1)
        if self.batch_size % self.minibatch_size != 0:
            raise PvedError(
                f"PPOConfig.minibatch_size {self.minibatch_size} must divide the batch "
                f"num_envs*steps_per_env = {self.batch_size}"
            )
        check_number("gamma", self.gamma, low=0.0, high=1.0, low_open=True)
        check_number("gae_lambda", self.gae_lambda, low=0.0, high=1.0)
        for name in ("lr", "adam_eps", "clip", "max_grad_norm", "obs_clip", "reward_clip"):
            check_number(name, getattr(self, name), low=0.0, low_open=True)
        for name in ("clip_value", "target_kl"):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), low=0.0, low_open=True)
        check_number("ent_coef", self.ent_coef, low=0.0)
        check_number("vf_coef", self.vf_coef, low=0.0)
        check_number("init_log_std", self.init_log_std)
        check_int("checkpoint_every", self.checkpoint_every, low=0)
        check_int("eval_every", self.eval_every, low=0)
        check_seed("seed", self.seed)
        for name in ("anneal_lr", "normalize_advantage", "normalize_obs", "normalize_reward"):
            if not isinstance(getattr(self, name), bool):
                raise OptionError(name, getattr(self, name), "true or false")
        check_activation(self.activation)
        if self.backend not in BACKENDS:
            raise PvedError(f"PPOConfig.backend must be one of {BACKENDS}, got {self.backend!r}")

    @property
    def batch_size(self) -> int:
        """N·T transitions per update."""
        return self.num_envs * self.steps_per_env

    @property
    def num_updates(self) -> int:
        """Updates needed to reach ``total_steps``."""
        return -(-self.total_steps // self.batch_size)

    def to_dict(self) -> dict[str, Any]:
        return cast(dict[str, Any], to_jsonable(self))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PPOConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise :class:`PvedError`."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise PvedError(f"unknown PPOConfig field(s): {', '.join(unknown)}")
        return cls(**dict(data))


# ========================================================================================
# 2. Training
# ========================================================================================


EvalFn = Callable[[Policy, int], Mapping[str, float]]


def _env_state_api(env: BatchedEnv) -> tuple[Callable[[], Any], Callable[[Any], None]] | None:
    """The env's optional exact save/restore pair.

    A BatchedEnv that can capture everything its future depends on (MuJoCo integration
    state incl. warm start, step counters, per-copy generators) exposes
    ``state_dict() -> dict`` (numpy arrays and plain data) and ``load_state_dict(dict)``;
    PPO checkpoints then resume bit-exactly. Wrappers should forward both; a wrapper's
    ``state_dict()`` returns None when the env it wraps cannot save (the checkpoint then
    holds no env state, and a resume starts fresh episodes).
    """
    save = getattr(env, "state_dict", None)
    load = getattr(env, "load_state_dict", None)
    if callable(save) and callable(load):
        return save, load
    return None


def _deferred_terms_api(env: BatchedEnv) -> Callable[[], np.ndarray] | None:
    """The env's optional deferred reward terms.

    A wrapper that adds a term to the reward (Eq. 10's shaping) may compute it for a whole
    rollout at once, far cheaper than step by step (one encoder batch for many steps).
    It exposes ``defer_terms()``, which PPO calls once to switch it on; from then on its
    ``step`` returns the reward without the term (``info["env_reward"]`` still set), and
    ``deferred_terms() -> (T, N)`` returns the terms of the steps since the last call, in
    order, exactly the values ``step`` would have added. PPO asks for them at the end of
    every rollout, before it reads any reward.
    """
    defer = getattr(env, "defer_terms", None)
    terms = getattr(env, "deferred_terms", None)
    if callable(defer) and callable(terms):
        defer()
        return cast(Callable[[], np.ndarray], terms)
    return None


def _to_saveable(obj: Any) -> Any:
    """numpy arrays → tensors (recursively) so a state loads with weights_only=True."""
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(obj).copy())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {k: _to_saveable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_to_saveable(v) for v in obj)
    return obj


def _from_saveable(obj: Any) -> Any:
    """Inverse of :func:`_to_saveable` (tensors → numpy arrays)."""
    if isinstance(obj, torch.Tensor):
        return obj.numpy().copy()
    if isinstance(obj, Mapping):
        return {k: _from_saveable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_from_saveable(v) for v in obj)
    return obj


class _Trainer:
    """The mutable state of one PPO run and the steps that advance it. Kept as one
    object so that checkpoints capture *all* of it (resuming is then bit-exact for envs
    that can save their state)."""

    def __init__(self, env: BatchedEnv, config: PPOConfig) -> None:
        self.env, self.cfg = env, config
        obs_space, act_space = env.single_observation_space, env.single_action_space
        if len(obs_space.shape or ()) != 1 or len(act_space.shape or ()) != 1:
            raise PvedError("PPO needs flat Box observation and action spaces")
        if env.num_envs != config.num_envs:
            raise PvedError(
                f"PPOConfig.num_envs is {config.num_envs} but the env has {env.num_envs} copies"
            )
        self.obs_dim = int(obs_space.shape[0])
        self.act_dim = int(act_space.shape[0])
        self.low = np.asarray(act_space.low, dtype=np.float64)
        self.high = np.asarray(act_space.high, dtype=np.float64)
        if not (np.all(np.isfinite(self.low)) and np.all(np.isfinite(self.high))):
            raise PvedError("PPO needs a bounded action space (finite low and high)")

        self.net = ActorCritic(
            self.obs_dim, self.act_dim, config.hidden_sizes, config.activation, config.init_log_std
        )
        self.net.init_weights(config.seed)
        self.flat = FlatParams(self.net.ordered_parameters())
        # numpy views of the parameters and of their gradients, layer by layer
        self.actor, self.critic, self.log_std = actor_critic_views(self.flat.params_np, self.net)
        self.actor_g, self.critic_g, self.log_std_g = actor_critic_views(
            self.flat.grads_np, self.net
        )
        self.adam = FlatAdam(self.flat.flat_np.size, config.adam_eps)
        self.obs_norm = ObsNormalizer(self.obs_dim, config.normalize_obs, config.obs_clip)
        self.ret_rms = RunningMeanStd(())
        self.ret_acc = np.zeros(config.num_envs, dtype=np.float64)
        self.rng = np.random.default_rng(config.seed)
        self.global_step = 0
        self.update = 0
        self.elapsed = 0.0
        self.ep_ret = np.zeros(config.num_envs, dtype=np.float64)
        self.ep_len = np.zeros(config.num_envs, dtype=np.int64)
        self.reward_terms: dict[str, float] = {}  # per-step means of the last rollout
        # share of the last rollout's scaled env rewards the ±reward_clip bound
        self.clipped_share = 0.0
        self.obs = np.zeros((config.num_envs, self.obs_dim), dtype=np.float64)
        self.next_checkpoint = config.checkpoint_every
        self.next_eval = 0
        self.policy = Policy(self.net, self.obs_norm, self.low, self.high, {"seed": config.seed})
        # a shaped env that encodes the policy's mean action takes it before each step
        give_mean = getattr(env, "set_mean_actions", None)
        self.give_mean: Callable[[np.ndarray], None] | None = (
            give_mean if callable(give_mean) else None
        )
        # an env may offer a loss on the mean action itself (pved.rl.guide; pved-align)
        guide = getattr(env, "action_guide", None)
        if guide is not None and not isinstance(guide, ActionGuide):
            raise PvedError(f"{type(env).__name__}.action_guide is not an ActionGuide")
        self.guide: ActionGuide | None = guide
        # off for the rest of the run once the task is being found (pved.rl.guide)
        self.gate: RewardGate | None = (
            RewardGate(
                score=getattr(guide, "gate_score", None),
                min_gap=getattr(guide, "gate_min_gap", 0.0),
            )
            if guide is not None
            else None
        )
        # the guide's parameter gradient, kept apart from PPO's until PPO's is clipped
        self.guide_grad = np.zeros_like(self.flat.grad_np)
        self.guide_actor_g = actor_critic_views(
            [
                self.guide_grad[sl].reshape(g.shape)
                for sl, g in zip(self.flat.slices, self.flat.grads_np, strict=True)
            ],
            self.net,
        )[0]
        self.deferred_terms = _deferred_terms_api(env)

        T, N, A = config.steps_per_env, config.num_envs, self.act_dim
        self.buf_obs = np.zeros((T, N, self.obs_dim), dtype=np.float32)
        self.buf_act = np.zeros((T, N, A), dtype=np.float32)
        self.buf_logp = np.zeros((T, N), dtype=np.float32)
        self.buf_val = np.zeros((T, N), dtype=np.float32)
        self.buf_rew = np.zeros((T, N), dtype=np.float64)
        self.buf_done = np.zeros((T, N), dtype=bool)
        self.buf_term = np.zeros((T, N), dtype=bool)
        self.buf_boot = np.zeros((T, N), dtype=np.float32)
        self.buf_trunc = np.zeros((T, N), dtype=bool)
        self.buf_ctx = np.zeros((T, N, guide.context_dim if guide else 0), dtype=np.float32)
        self.buf_gmask = np.ones((T, N), dtype=np.float32)  # the env's GUIDE_MASK
        # each step's reward as the env gave it, its env part (info["env_reward"]) and its
        # shaping term (added after the rollout when deferred); read by _account
        self.buf_given = np.zeros((T, N), dtype=np.float64)
        self.buf_env_part = np.zeros((T, N), dtype=np.float64)
        self.buf_shaping = np.zeros((T, N), dtype=np.float64)

    # -- start / checkpoint ----------------------------------------------------------
    def reset_env(self, seed: int) -> None:
        obs, _ = self.env.reset(seed=seed)
        self.obs = np.asarray(obs, dtype=np.float64)
        self.obs_norm.update(self.obs)

    def state_dict(self) -> dict[str, Any]:
        env_state = _env_state_api(self.env)
        return {
            "format": CHECKPOINT_FORMAT,
            "config": self.cfg.to_dict(),
            "pved_version": __version__,
            "global_step": self.global_step,
            "update": self.update,
            "elapsed": self.elapsed,
            "params": self.flat.flat.clone(),
            "adam": self.adam.state_dict(),
            "obs_norm": self.obs_norm.state_dict(),
            "ret_rms": {
                "mean": float(self.ret_rms.mean),
                "var": float(self.ret_rms.var),
                "count": self.ret_rms.count,
            },
            "ret_acc": torch.from_numpy(self.ret_acc.copy()),
            "rng": self.rng.bit_generator.state,
            "obs": torch.from_numpy(self.obs.copy()),
            "ep_ret": torch.from_numpy(self.ep_ret.copy()),
            "ep_len": torch.from_numpy(self.ep_len.copy()),
            "next_checkpoint": self.next_checkpoint,
            "next_eval": self.next_eval,
            "env_state": _to_saveable(env_state[0]()) if env_state else None,
            "guide_gate": None if self.gate is None else self.gate.state_dict(),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        if state.get("format") != CHECKPOINT_FORMAT:
            raise PvedError("the run's checkpoint is not a pved PPO checkpoint")
        if state.get("config") != self.cfg.to_dict():
            raise PvedError(
                "the run's checkpoint was written with a different PPOConfig; "
                "use a new run directory"
            )
        params = cast(torch.Tensor, state["params"])
        if params.shape != self.flat.flat.shape:
            raise PvedError("the checkpoint's networks do not match this env's dimensions")
        self.flat.flat.copy_(params)
        self.adam.load_state_dict(state["adam"])
        self.obs_norm.load_state_dict(dict(state["obs_norm"]))
        self.ret_rms.mean = np.asarray(state["ret_rms"]["mean"], dtype=np.float64)
        self.ret_rms.var = np.asarray(state["ret_rms"]["var"], dtype=np.float64)
        self.ret_rms.count = float(state["ret_rms"]["count"])
        self.ret_acc = state["ret_acc"].numpy().copy()
        self.rng.bit_generator.state = state["rng"]
        self.ep_ret = state["ep_ret"].numpy().copy()
        self.ep_len = state["ep_len"].numpy().copy()
        self.global_step = int(state["global_step"])
        self.update = int(state["update"])
        self.elapsed = float(state["elapsed"])
        self.next_checkpoint = int(state["next_checkpoint"])
        self.next_eval = int(state["next_eval"])
        if self.gate is not None and state.get("guide_gate") is not None:
            self.gate.load_state_dict(dict(state["guide_gate"]))
        env_state = _env_state_api(self.env)
        if state.get("env_state") is not None and env_state:
            env_state[1](_from_saveable(state["env_state"]))
            self.obs = state["obs"].numpy().copy()
        else:
            # The env cannot restore its episodes: start fresh ones, seeded by the update
            # index so the resumed run is still reproducible (but not identical to an
            # uninterrupted one).
            warnings.warn(
                f"{type(self.env).__name__} has no state_dict/load_state_dict: resuming PPO with "
                "freshly reset episodes, so the result will differ from an uninterrupted run",
                stacklevel=3,
            )
            self.reset_env(self.cfg.seed + 1_000_003 * self.update)
            self.ep_ret[:] = 0.0
            self.ep_len[:] = 0
            self.ret_acc[:] = 0.0

    # -- rollout ---------------------------------------------------------------------
    def _forward(self, obs_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """obs_n (N, O) normalised → (mean (N, A), value (N,)): one forward for all envs."""
        mean, _ = mlp_forward_np(obs_n, self.actor, self.cfg.activation)
        value, _ = mlp_forward_np(obs_n, self.critic, self.cfg.activation)
        return mean, value[:, 0]

    def _value(self, obs_n: np.ndarray) -> np.ndarray:
        value, _ = mlp_forward_np(obs_n, self.critic, self.cfg.activation)
        return value[:, 0]

    def rollout(self) -> dict[str, list[float]]:
        """Collect T steps from all N envs into the buffers; returns finished episodes'
        returns, lengths and successes."""
        cfg = self.cfg
        std = np.exp(self.log_std)
        self.buf_trunc[:] = False
        # per-step sums of the env's named reward terms (and of the shaping wrapper's
        # env_reward / reward_shaping), so a shaped run shows what each part contributed
        term_sums: dict[str, float] = {}
        shaped = False  # whether the env's reward carries a shaping term
        successes: list[np.ndarray | None] = []  # per step: is_success of its copies
        # per step: the entry the reward gate scores a finished episode by, where it has one
        gate_key = None if self.gate is None or not self.gate.open else self.gate.info_key
        gate_values: list[np.ndarray | None] = []
        for t in range(cfg.steps_per_env):
            obs_n = self.obs_norm(self.obs)
            mean, value = self._forward(obs_n)
            noise = self.rng.standard_normal(mean.shape, dtype=np.float32)
            action = mean + std * noise
            self.buf_obs[t] = obs_n
            self.buf_act[t] = action
            self.buf_logp[t] = gaussian_log_prob_np(action, mean, self.log_std)
            self.buf_val[t] = value
            if self.give_mean is not None:  # a shaped env encodes the mean action (Eq. 10)
                self.give_mean(np.clip(mean.astype(np.float64), self.low, self.high))

            next_obs, reward, terminated, truncated, info = self.env.step(
                np.clip(action.astype(np.float64), self.low, self.high)
            )
            terminated = np.asarray(terminated, dtype=bool)
            done = terminated | np.asarray(truncated, dtype=bool)
            self.obs = np.asarray(next_obs, dtype=np.float64)
            if self.guide is not None:  # the context of the step just taken (pre-step state)
                self.buf_ctx[t] = np.asarray(info[GUIDE_CONTEXT], dtype=np.float32)
                self.buf_gmask[t] = np.asarray(info.get(GUIDE_MASK, 1.0), dtype=np.float32)
            for key, value in info.items():
                # reward terms, and shares of steps (0/1 per copy, e.g. past the source's end)
                if key.startswith(("reward_", "share_")) or key == "env_reward":
                    term_sums[key] = term_sums.get(key, 0.0) + float(np.sum(value))
            reward = np.asarray(reward, dtype=np.float64)
            self.buf_given[t] = reward
            if "reward_shaping" in info:
                shaped = True
                term = np.asarray(info["reward_shaping"], dtype=np.float64)
                self.buf_shaping[t] = term
                self.buf_env_part[t] = np.asarray(info.get("env_reward", reward - term), np.float64)
            else:
                self.buf_env_part[t] = reward
            successes.append(
                np.asarray(info["is_success"], dtype=np.float64) if "is_success" in info else None
            )
            if gate_key is not None:
                gate_values.append(
                    np.asarray(info[gate_key], dtype=np.float64) if gate_key in info else None
                )
            self.buf_done[t] = done
            self.buf_term[t] = terminated
            self.obs_norm.update(self.obs)

            # truncated (not terminated) episodes bootstrap from V(final_obs)
            boot = done & ~terminated
            if boot.any():
                idx = np.flatnonzero(boot)
                final = np.asarray(info["final_obs"], dtype=np.float64)[idx]
                self.buf_boot[t, idx] = self._value(self.obs_norm(final))
                self.buf_trunc[t, idx] = True
        if self.deferred_terms is not None:
            # the env left its shaping term out of each step's reward: add it now, as if
            # it had come with the step (the reward and info the env would have given)
            terms = np.asarray(self.deferred_terms(), dtype=np.float64)
            shaped = True
            self.buf_shaping[:] = terms
            self.buf_env_part[:] = self.buf_given
            self.buf_given += terms
            term_sums["reward_shaping"] = float(np.sum(terms))
        episodes = self._account(shaped, successes, gate_values if gate_key else None)
        self.global_step += cfg.batch_size
        if self.gate is not None:
            self.gate.observe(
                episodes["return"],
                episodes["length"],
                episodes["success"],
                self.global_step,
                episodes["gate_value"] if gate_key else episodes["completed"],
            )
        self.reward_terms = {k: v / cfg.batch_size for k, v in term_sums.items()}
        return episodes

    def _account(
        self,
        shaped: bool,
        successes: list[np.ndarray | None],
        gate_values: list[np.ndarray | None] | None = None,
    ) -> dict[str, list[float]]:
        """The rollout's rewards, step by step in the order they came: episode statistics
        on the env's reward, then the reward PPO optimises into ``buf_rew`` (normalised
        when ``normalize_reward``); returns the finished episodes' statistics (and, with
        ``gate_values``, the reward gate's entry at each one's last step)."""
        cfg = self.cfg
        episodes: dict[str, list[float]] = {
            "return": [],
            "length": [],
            "success": [],
            "completed": [],  # ran to the time limit without terminating
            "gate_value": [],
        }
        clip_hits = 0  # steps whose scaled env reward the ±reward_clip bound
        for t in range(cfg.steps_per_env):
            reward = self.buf_given[t]
            done = self.buf_done[t]
            # episode statistics on the reward the env gave
            self.ep_ret += reward
            self.ep_len += 1
            if done.any():
                idx = np.flatnonzero(done)
                episodes["return"].extend(self.ep_ret[idx].tolist())
                episodes["length"].extend(self.ep_len[idx].tolist())
                episodes["completed"].extend((~self.buf_term[t][idx]).astype(float).tolist())
                success = successes[t]
                if success is not None:
                    episodes["success"].extend(success[idx].tolist())
                value = None if gate_values is None else gate_values[t]
                if value is not None:
                    episodes["gate_value"].extend(value[idx].tolist())
                self.ep_ret[idx] = 0.0
                self.ep_len[idx] = 0

            if cfg.normalize_reward:
                # Rewards are divided by the running std σ of the discounted return of the
                # reward optimised, and the env reward is clipped to ±clip as in plain PPO.
                # A shaped env's term (info["reward_shaping"]) is divided by the same σ and
                # never clipped, so the reward is (r_env − β·D)/σ, Eq. 10's sum times one
                # positive number, wherever the env clip does not bind (as often as in
                # plain PPO): β weighs the term linearly, and a zero term is plain PPO
                # (docs/decisions.md, "Reward normalisation under shaping").
                self.ret_acc = self.ret_acc * cfg.gamma + reward
                self.ret_rms.update(self.ret_acc)
                scale = math.sqrt(float(self.ret_rms.var) + 1e-8)
                scaled = self.buf_env_part[t] / scale
                clip_hits += int(np.count_nonzero(np.abs(scaled) > cfg.reward_clip))
                reward = np.clip(scaled, -cfg.reward_clip, cfg.reward_clip)
                if shaped:
                    reward = reward + self.buf_shaping[t] / scale
                self.ret_acc[done] = 0.0
            self.buf_rew[t] = reward
        self.clipped_share = clip_hits / cfg.batch_size
        return episodes

    def advantages(self) -> tuple[np.ndarray, np.ndarray]:
        """GAE over the buffers → advantages, returns (T, N)."""
        last_value = self._value(self.obs_norm(self.obs))
        next_values = np.concatenate([self.buf_val[1:], last_value[None]], axis=0)
        next_values = np.where(self.buf_trunc, self.buf_boot, next_values)
        next_values[self.buf_term] = 0.0
        return compute_gae(
            self.buf_rew,
            self.buf_val,
            self.buf_done,
            next_values,
            self.cfg.gamma,
            self.cfg.gae_lambda,
        )

    # -- update ----------------------------------------------------------------------
    def _guide(
        self, ctx: np.ndarray | None, mean: np.ndarray, mask: np.ndarray | None = None
    ) -> tuple[dict[str, float], np.ndarray] | None:
        """The guide's statistics (its loss first) and dL/dmean (B, A) at a minibatch; None
        without a guide or once :class:`RewardGate` has closed. Rows of ``mask`` 0 (no
        source to compare with) are left out and count as 0 in the guide's mean."""
        if self.guide is None or ctx is None or (self.gate is not None and not self.gate.open):
            return None
        # the rollout just counted has been taken: the share done before this update
        progress = (self.global_step - self.cfg.batch_size) / max(self.cfg.total_steps, 1)
        mean32 = np.asarray(mean, dtype=np.float32)
        keep = None if mask is None else np.asarray(mask) > 0
        if keep is None or keep.all():
            loss, grad = self.guide.loss_grad(ctx, mean32, progress)
            stats = {"guide_loss": float(loss), "guide_rows": 1.0}
            full = np.asarray(grad, dtype=np.float32).reshape(mean.shape)
        else:
            share = float(keep.mean())
            stats = {"guide_loss": 0.0, "guide_rows": share}
            full = np.zeros(mean.shape, dtype=np.float32)
            if share > 0:  # a mean over the rows kept, as one over all with 0 at the others
                loss, grad = self.guide.loss_grad(ctx[keep], mean32[keep], progress)
                stats["guide_loss"] = share * float(loss)
                full[keep] = np.float32(share) * np.asarray(grad, dtype=np.float32).reshape(
                    int(keep.sum()), -1
                )
        extra = getattr(self.guide, "last_stats", None)
        if isinstance(extra, Mapping):
            stats.update({f"guide_{k}": float(v) for k, v in extra.items()})
        return stats, full

    def _grad_numpy(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        logp: np.ndarray,
        adv: np.ndarray,
        ret: np.ndarray,
        val: np.ndarray,
        ctx: np.ndarray | None = None,
        mask: np.ndarray | None = None,
    ) -> dict[str, float]:
        """PPO's gradient into ``flat.grad_np`` and, with a guide, the guide's parameter
        gradient into :attr:`guide_grad` (its stats then carry ``guide_loss``)."""
        cfg = self.cfg
        mean, a_hidden = mlp_forward_np(obs, self.actor, cfg.activation)
        value, c_hidden = mlp_forward_np(obs, self.critic, cfg.activation)
        stats, d_mean, d_log_std, d_value = ppo_loss_grad(
            mean, self.log_std, value[:, 0], act, logp, adv, ret, val,
            clip=cfg.clip, clip_value=cfg.clip_value, ent_coef=cfg.ent_coef,
            vf_coef=cfg.vf_coef, normalize_advantage=cfg.normalize_advantage,
        )  # fmt: skip
        mlp_backward_np(obs, a_hidden, d_mean, self.actor, self.actor_g, cfg.activation)
        mlp_backward_np(obs, c_hidden, d_value[:, None], self.critic, self.critic_g, cfg.activation)
        self.log_std_g[...] = d_log_std
        guided = self._guide(ctx, mean, mask)
        if guided is not None:
            stats.update(guided[0])
            stats["loss"] += guided[0]["guide_loss"]
            # the guide reaches the actor only; the critic's and log-std's parts stay 0
            mlp_backward_np(
                obs, a_hidden, guided[1], self.actor, self.guide_actor_g, cfg.activation
            )
        return stats

    def _grad_torch(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        logp: np.ndarray,
        adv: np.ndarray,
        ret: np.ndarray,
        val: np.ndarray,
        ctx: np.ndarray | None = None,
        mask: np.ndarray | None = None,
    ) -> dict[str, float]:
        """:meth:`_grad_numpy` by autograd."""
        cfg = self.cfg
        t = torch.from_numpy
        mean, value = self.net(t(obs))
        loss, st = ppo_loss(
            mean, self.net.log_std, value, t(act), t(logp), t(adv), t(ret), t(val),
            clip=cfg.clip, clip_value=cfg.clip_value, ent_coef=cfg.ent_coef,
            vf_coef=cfg.vf_coef, normalize_advantage=cfg.normalize_advantage,
        )  # fmt: skip
        out = {"loss": float(loss.detach()), **{k: float(v) for k, v in st.items()}}
        guided = self._guide(ctx, mean.detach().numpy(), mask)
        self.net.zero_grad(set_to_none=True)
        loss.backward(retain_graph=guided is not None)
        self.flat.grads_from_torch()
        if guided is not None:  # mean · (dL/dmean), dL/dmean held fixed: the guide's gradient
            out.update(guided[0])
            out["loss"] += guided[0]["guide_loss"]
            self.net.zero_grad(set_to_none=True)
            (mean * torch.from_numpy(guided[1])).sum().backward()
            for p, sl in zip(self.flat.params, self.flat.slices, strict=True):
                self.guide_grad[sl] = 0.0 if p.grad is None else p.grad.numpy().reshape(-1)
        return out

    def _add_guide(self, stats: dict[str, float]) -> None:
        """Add :attr:`guide_grad`, scaled to a norm of at most ``GUIDE_GRAD_RATIO`` times
        PPO's clipped gradient's, to ``flat.grad_np`` (pved.rl.guide): PPO's own update is
        the one it would take without a guide, and the guide adds at most ρ of it."""
        grad, guide = self.flat.grad_np, self.guide_grad
        ppo_norm = math.sqrt(float(np.dot(grad, grad)))
        guide_norm = math.sqrt(float(np.dot(guide, guide)))
        if not math.isfinite(guide_norm):
            raise PvedError(f"NaN/inf in the guide's gradient at update {self.update + 1}")
        bound = GUIDE_GRAD_RATIO * ppo_norm
        scale = 1.0 if guide_norm <= bound else bound / guide_norm
        if guide_norm > 0:
            grad += np.float32(scale) * guide
        stats["guide_grad_norm"] = guide_norm
        stats["guide_grad_ratio"] = scale * guide_norm / ppo_norm if ppo_norm > 0 else 0.0
        stats["guide_bounded"] = float(guide_norm > bound)

    def learn(self, advantages: np.ndarray, returns: np.ndarray) -> dict[str, float]:
        """``epochs`` passes of shuffled minibatch steps over the rollout."""
        cfg = self.cfg
        lr = cfg.lr * (1.0 - self.update / cfg.num_updates) if cfg.anneal_lr else cfg.lr
        n = cfg.batch_size
        data = (
            self.buf_obs.reshape(n, self.obs_dim),
            self.buf_act.reshape(n, self.act_dim),
            self.buf_logp.reshape(n),
            advantages.reshape(n).astype(np.float32),
            returns.reshape(n).astype(np.float32),
            self.buf_val.reshape(n),
            self.buf_ctx.reshape(n, self.buf_ctx.shape[-1]),
            self.buf_gmask.reshape(n),
        )
        grad_fn = self._grad_numpy if cfg.backend == "numpy" else self._grad_torch
        sums: dict[str, float] = {}
        steps = 0
        stop = False
        for _ in range(cfg.epochs):
            # one permutation per epoch, applied once; minibatches are then slices
            perm = self.rng.permutation(n)
            shuffled = [x[perm] for x in data]
            for start in range(0, n, cfg.minibatch_size):
                mb = [x[start : start + cfg.minibatch_size] for x in shuffled]
                stats = grad_fn(*mb)
                if not math.isfinite(stats["loss"]):
                    raise PvedError(f"NaN/inf in PPO loss at update {self.update + 1}")
                if cfg.target_kl is not None and stats["approx_kl"] > 1.5 * cfg.target_kl:
                    stop = True
                    break
                norm = clip_grad_norm_np(self.flat.grad_np, cfg.max_grad_norm)
                if not math.isfinite(norm):
                    raise PvedError(f"NaN/inf in PPO gradient at update {self.update + 1}")
                if "guide_loss" in stats:  # after PPO's own clip, bounded by it
                    self._add_guide(stats)
                self.adam.step(self.flat.flat_np, self.flat.grad_np, lr)
                stats["grad_norm"] = norm
                for k, v in stats.items():
                    sums[k] = sums.get(k, 0.0) + v
                steps += 1
            if stop:
                break
        self.update += 1
        out = {k: v / max(steps, 1) for k, v in sums.items()}
        values, rets = self.buf_val.reshape(-1), returns.reshape(-1)
        var_ret = float(np.var(rets))
        out["explained_variance"] = (
            float("nan") if var_ret == 0 else 1.0 - float(np.var(rets - values)) / var_ret
        )
        out["lr"] = lr
        out["minibatch_steps"] = float(steps)
        out["std_mean"] = float(np.exp(self.log_std).mean())
        return out


#: Wall-clock seconds between the checkpoints :func:`train_ppo` takes besides those every
#: ``checkpoint_every`` env steps: a kill then loses about a minute of training, not up to
#: 100k steps (hours of a slow body's). A checkpoint costs a few milliseconds.
CHECKPOINT_SECONDS = 60.0


def check_checkpoint_seconds(value: object, option: str = "checkpoint_every_s") -> float | None:
    """A time between checkpoints: a number of seconds >= 0 (0: after every update), or
    None or inf for none by time; else :class:`OptionError` naming ``option``."""
    if value is None:
        return None
    seconds = check_number(option, value, low=0.0, infinite=True)
    return None if math.isinf(seconds) else seconds


def train_ppo(
    env: BatchedEnv,
    config: PPOConfig,
    run: Run | None = None,
    *,
    eval_fn: EvalFn | None = None,
    stop_fn: Callable[[], bool] | None = None,
    progress: bool = True,
    env_id: str | None = None,
    checkpoint_every_s: float | None = CHECKPOINT_SECONDS,
    clock: Callable[[], float] = time.monotonic,
) -> Policy:
    """Train a Gaussian actor-critic with PPO on ``env`` and return the policy.

    Each update collects ``steps_per_env`` steps from every copy of ``env`` (one policy
    forward for all copies per step), computes GAE with truncation bootstrapping, and runs
    ``epochs`` passes of minibatch steps on the clipped objective.

    With a ``run``: ``run.start()`` is called, training resumes from
    ``run.latest_checkpoint()`` if there is one, every update logs its episode statistics
    (``episode/return_mean``, ``episode/length_mean``, ``episode/success_rate`` when the
    env reports ``is_success``), losses, approx-KL, clip fraction and steps/s to
    ``run.log``; a full checkpoint (networks, optimiser, normalisers, RNG, env state when
    the env has ``state_dict``/``load_state_dict``, step counter) is saved every
    ``checkpoint_every`` env steps, and after the first update that ends
    ``checkpoint_every_s`` seconds of wall time after the last checkpoint (or the start);
    the final policy is saved to ``run.path / "policy.pt"``. ``result.json`` is left to
    the caller.

    Args:
        env: any BatchedEnv with flat Box spaces and ``num_envs == config.num_envs``.
        config: hyper-parameters.
        run: the stage's run directory, or None for no files.
        eval_fn: called as ``eval_fn(policy, env_steps)`` at step 0, every
            ``eval_every`` env steps and at the end; its floats are logged under
            ``eval/`` (keys already starting with ``eval/`` are kept as they are).
            It must not step ``env`` (use its own env) so that training stays
            reproducible.
        stop_fn: called after each evaluation before the last (once its result is
            logged); True ends training there, and the policy of that point is the one
            returned and saved.
        progress: show a tqdm progress bar.
        env_id: name stored in the policy's metadata (default: the env's ``env_id``
            attribute or class name).
        checkpoint_every_s: seconds of wall time between checkpoints by time (0: after
            every update; None or inf: by steps only). Not part of ``config``: when a
            checkpoint is taken does not change what the run computes, since every one
            is taken between two whole updates and resumes exactly.
        clock: the wall clock those seconds are read from (tests give their own).

    Returns:
        The trained :class:`Policy` (with its observation normaliser).

    Raises:
        PvedError: bad config/env, a checkpoint from another config, or NaN/inf in the
            loss ("NaN/inf in PPO loss at update k").
    """
    every_s = check_checkpoint_seconds(checkpoint_every_s)
    torch.set_num_threads(1)
    trainer = _Trainer(env, config)
    state = None
    if run is not None:
        run.start()
        state = run.latest_checkpoint()
    if state is not None:
        trainer.load_state_dict(state)
    else:
        trainer.reset_env(config.seed)
    if run is not None:  # a run killed before its first checkpoint starts over
        run.drop_metrics_after(
            trainer.global_step if state is not None else -1,
            # resumed from its last checkpoint: the final evaluation is made again below
            final_eval=state is not None and trainer.update >= config.num_updates,
        )

    name = env_id or str(getattr(env, "env_id", type(env).__name__))
    policy = trainer.policy
    policy.metadata.update(env_id=name, seed=config.seed, ppo_config=config.to_dict())
    total = config.num_updates * config.batch_size
    bar = tqdm(
        total=total,
        initial=trainer.global_step,
        unit="step",
        disable=not progress,
        dynamic_ncols=True,
        desc="PPO",
    )

    def maybe_eval(final: bool) -> bool:
        """Evaluate when due (or at the end); True when ``stop_fn`` ends training."""
        if eval_fn is None:
            return False
        due = trainer.global_step >= trainer.next_eval
        if not (due or final):
            return False
        if due:
            interval = config.eval_every if config.eval_every > 0 else total + 1
            while trainer.next_eval <= trainer.global_step:
                trainer.next_eval += interval
        policy.metadata["training_steps"] = trainer.global_step
        raw = dict(eval_fn(policy, trainer.global_step))
        result = {k if k.startswith("eval/") else f"eval/{k}": float(v) for k, v in raw.items()}
        if run is not None and result:
            run.log(trainer.global_step, **result)
        return not final and stop_fn is not None and stop_fn()

    last_checkpoint = clock()
    try:
        if trainer.global_step == 0:
            maybe_eval(final=False)
        while trainer.update < config.num_updates:
            t0 = time.perf_counter()
            episodes = trainer.rollout()
            advantages, returns = trainer.advantages()
            stats = trainer.learn(advantages, returns)
            dt = time.perf_counter() - t0
            trainer.elapsed += dt

            scalars = {f"loss/{k}": v for k, v in stats.items()}
            scalars["time/steps_per_s"] = config.batch_size / dt
            scalars["time/steps_per_s_mean"] = trainer.global_step / max(trainer.elapsed, 1e-9)
            scalars.update({f"rollout/{k}": v for k, v in trainer.reward_terms.items()})
            scalars["rollout/clipped_share"] = trainer.clipped_share
            if trainer.gate is not None:
                scalars.update(trainer.gate.scalars())
            if episodes["return"]:
                scalars["episode/return_mean"] = float(np.mean(episodes["return"]))
                scalars["episode/length_mean"] = float(np.mean(episodes["length"]))
                scalars["episode/count"] = float(len(episodes["return"]))
                bar.set_postfix(ret=f"{scalars['episode/return_mean']:.1f}", refresh=False)
            if episodes["success"]:
                scalars["episode/success_rate"] = float(np.mean(episodes["success"]))
            if run is not None:
                run.log(trainer.global_step, **scalars)
            bar.update(config.batch_size)

            last = trainer.update >= config.num_updates
            if not last and maybe_eval(final=False):
                break
            by_steps = (
                config.checkpoint_every > 0 and trainer.global_step >= trainer.next_checkpoint
            )
            by_time = every_s is not None and clock() - last_checkpoint >= every_s
            if run is not None and (by_steps or by_time):
                # A checkpoint by time leaves the schedule by steps as it is: the state
                # saved is the same at either, so a resume from one goes on exactly.
                if by_steps:
                    while trainer.next_checkpoint <= trainer.global_step:
                        trainer.next_checkpoint += config.checkpoint_every
                run.save_checkpoint(trainer.global_step, trainer.state_dict())
                last_checkpoint = clock()
        else:
            maybe_eval(final=True)
    finally:
        bar.close()

    policy.metadata.update(
        training_steps=trainer.global_step, obs_dim=trainer.obs_dim, act_dim=trainer.act_dim
    )
    if run is not None:
        policy.save(run.path / "policy.pt")
    return policy
