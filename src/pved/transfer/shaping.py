"""Reward shaping through the shared subspace (paper Eq. 10).

    r_t = r_env(s_T, a_T) − β · KL( q_φS(c | s_S, a_S) ‖ q_φT(c | s_T, a_T) )

(s_S, a_S) is the source's state-action at the same moment of the bank episode matched
to this target episode, on the time base the pairs were aligned on (``source_bank.py``).
For a model with a deterministic shared space the distance replaces the KL
(``SharedSpaceModel.shaping``).

a_T is the target policy's mean action at s_T (clipped to the action box), as in the
pairs the encoders were trained on and in the bank, not the sampled exploration action
(``SHAPING_ACTIONS``; docs/decisions.md, "Which action Eq. 10 encodes"). A learner that
cannot give its mean action passes the action it took (``action="taken"``).

Two forms, one computation (:class:`LatentShaping`):

- :class:`ShapedBatchedEnv`, a :class:`BatchedEnv` for pved's own PPO;
- :class:`LatentShapingWrapper`, a plain ``gymnasium.Wrapper``, so any Gymnasium RL
  library (Stable-Baselines3, RLlib, CleanRL) can train on the shaped reward.

Both put the shaping term in ``info["reward_shaping"]`` (so the ``reward_*`` terms still
sum to the reward) and the unshaped env reward in ``info["env_reward"]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch

from pved.checks import check_number
from pved.envs.base import BatchedEnv, Info
from pved.errors import PvedError
from pved.models.base import SharedRep, SharedSpaceModel
from pved.rl.guide import GUIDE_CONTEXT, GUIDE_MASK
from pved.transfer.align_guide import ALIGN_ANNEAL, AlignGuide
from pved.transfer.prior_guide import PriorGuide, check_prior_model
from pved.transfer.source_bank import SourceBank, source_covered
from pved.transfer.source_cache import (
    MIN_BATCH_ROWS,
    EncodedBank,
    encode_bank,
    encode_batch_rows,
)

# How the distance D enters the reward: "eq10" is the paper's −β·D; "log1p" is
# −β·log(1 + D), an option outside the paper (docs/decisions.md, "A log-scaled shaping");
# "potential" takes Φ = −β·D as a potential and pays Φ_t − Φ_{t−1}/γ (outside the paper;
# docs/decisions/transfer.md, "A potential-based Eq. 10"); "align" adds no reward term
# but a loss on the policy's mean action, β·log(1 + D), annealed to 0 by half the run
# (outside the paper; :class:`AlignGuide`); "prior" adds no reward term but pulls the mean
# action towards the source's behaviour decoded into the target's action (outside the
# paper; :class:`PriorGuide`).
SHAPING_FORMS = ("eq10", "log1p", "potential", "align", "prior")
#: The forms that pay no reward term but give PPO a loss on the mean action (an ActionGuide).
GUIDE_FORMS = ("align", "prior")

#: The ``info`` key of the steps (N,) bool past the end of their source episode, compared
#: with nothing (``source_bank.source_covered``); PPO logs its share (``share_`` keys).
SOURCE_ENDED = "share_source_ended"

# Which target action Eq. 10 encodes: "mean" is the policy's mean action at s_T (what the
# pairs and the bank record), "taken" the sampled, clipped action the env was stepped with.
SHAPING_ACTIONS = ("mean", "taken")


def check_shaping_action(action: str) -> None:
    """Raise :class:`PvedError` for an action choice not in :data:`SHAPING_ACTIONS`."""
    if action not in SHAPING_ACTIONS:
        raise PvedError(f"unknown shaping action {action!r}; known: {', '.join(SHAPING_ACTIONS)}")


def check_shaping_form(form: str) -> None:
    """Raise :class:`PvedError` for a shaping form that is not in :data:`SHAPING_FORMS`."""
    if form not in SHAPING_FORMS:
        raise PvedError(f"unknown shaping form {form!r}; known: {', '.join(SHAPING_FORMS)}")


def task_params(info: dict[str, Any], keys: tuple[str, ...], n: int) -> np.ndarray:
    """The matching keys of ``info`` as one (n, K) array."""
    missing = [k for k in keys if k not in info]
    if missing:
        raise PvedError(f"env info lacks the task parameters {missing} the source bank matches on")
    if not keys:
        return np.zeros((n, 0))
    return np.concatenate([np.asarray(info[k], dtype=np.float64).reshape(n, -1) for k in keys], 1)


class LatentShaping:
    """Computes −β·D(source, target) for a batch of target state-actions.

    Args:
        model: a trained shared-space model (PVED or a variant); applies its own
            input standardisation.
        bank: source state-actions on the target task.
        beta: the shaping weight β of Eq. 10.
        robot_state_indices: indices of the target's robot state in its observation.
        start: env steps (rows shaped, over all calls) before which the term is 0: the
            target trains on its own reward alone until then. Not in the paper, whose β
            applies from the first step (``start=0``, the default); it asks whether the
            term hurts from the start, when it can be far larger than the task reward, or
            all along (docs/decisions.md).
        stop: env steps (rows shaped) by which the term's weight has fallen linearly from
            1 to 0, counted from the first row (0, the default: never, as in the paper);
            from then on the term is 0 and nothing is encoded. Not in the paper:
            ``pved-anneal`` (docs/decisions/transfer.md).
        form: ``"eq10"`` (the default) gives −β·D, the paper's term; ``"potential"``
            takes Φ_t = −β·D_t as a potential and pays Φ_t − Φ_{t−1}/γ at step t (look-back
            potential-based shaping, Wiewiora et al. 2003; Φ_{−1} = 0), whose discounted sum
            over an episode is γ^{T−1}·Φ_{T−1}: one step's term, however long the episode,
            so the target gains nothing by ending it early (the wrappers keep Φ_{t−1};
            :meth:`term`); ``"log1p"`` gives
            −β·log(1 + D). Not in the paper: a Gaussian KL grows with the squared gap
            between means over the learned variances, and on jaco-fetch it starts at
            millions of nats a step where matched training pairs cost under one
            (docs/results.md), so β can only trade a term that swamps the task reward
            for one too small to steer. log(1 + D) equals D for small D and grows
            slowly for large D, which keeps the term's ordering and compresses its range.
        time_scale: source steps per target step in the bank lookup
            (:func:`pved.transfer.source_bank.bank_time_scale`): 1 for pairs aligned by
            step, dt_T/dt_S for pairs aligned by physical time.
        action: which target action the wrappers encode, ``"mean"`` (the policy's mean
            action, given to the wrapper before each step; the default) or ``"taken"``
            (the action the env is stepped with).
        gamma: the learner's discount γ; only the ``"potential"`` form reads it.
        align_anneal: the share of the run over which a guide form's weight falls to 0
            (:data:`GUIDE_FORMS`: :class:`AlignGuide`, :class:`PriorGuide`); only they read it.
    """

    def __init__(
        self,
        model: SharedSpaceModel,
        bank: SourceBank,
        beta: float,
        robot_state_indices: np.ndarray,
        start: int = 0,
        form: str = "eq10",
        stop: int = 0,
        time_scale: float = 1.0,
        action: str = "mean",
        gamma: float = 0.99,
        align_anneal: float = ALIGN_ANNEAL,
    ) -> None:
        if start < 0:
            raise PvedError(f"the shaping start must be >= 0 env steps, not {start}")
        check_shaping_form(form)
        if form in GUIDE_FORMS and (start or stop):
            raise PvedError(
                f"the {form} form has no shaping start or stop (its weight anneals with PPO's "
                "progress instead: align_anneal)"
            )
        if form == "prior":  # refused here, before the run, not when PPO builds the guide
            check_prior_model(type(model))
        if stop < 0 or (stop and stop <= start):
            raise PvedError(f"the shaping stop must be 0 or after the start ({start}), not {stop}")
        if stop and form == "potential":
            raise PvedError("the potential form cannot be annealed: Φ must stay one function")
        check_shaping_action(action)
        if not (np.isfinite(time_scale) and time_scale > 0):
            raise PvedError(f"the bank's time scale must be a positive number, not {time_scale}")
        self.model = model.eval()
        self.bank = bank
        # as TransferConfig checks it: a negative beta would reward moving away from the
        # source, a NaN one turn every reward NaN (a notebook or an SB3 user builds this)
        self.beta = check_number("beta", beta, low=0.0)
        self.robot_state_indices = np.asarray(robot_state_indices, dtype=np.int64)
        self.start = int(start)
        self.stop = int(stop)
        self.form = form
        self.time_scale = float(time_scale)
        self.action = action
        self.gamma = check_number("gamma", gamma, low=0.0, high=1.0, low_open=True)
        self.align_anneal = check_number(
            "align_anneal", align_anneal, low=0.0, high=1.0, low_open=True
        )
        # rows shaped so far: the clock ``start`` and ``stop`` are read against (saved
        # with the env)
        self.steps = 0
        # q_φS of every bank row, encoded at the first shaped step (source_cache.py)
        self._encoded: EncodedBank | None = None
        if bank.dim != model.source_dim:
            raise PvedError(
                f"source bank rows have dim {bank.dim}, "
                f"the model's source input is {model.source_dim}"
            )

    def reward(
        self, obs: np.ndarray, action: np.ndarray, episode: np.ndarray, t: np.ndarray
    ) -> np.ndarray:
        """Shaping term (N,) for target observations (N, obs_dim) and actions (N, act_dim)
        at steps ``t`` (N,) of target episodes matched to bank ``episode`` (N,), times
        the weight :meth:`clock` gives this call's rows."""
        weight = self.clock(len(obs))
        if weight == 0.0:
            return np.zeros(len(obs))
        value = self.values(obs, action, episode, t, len(obs))
        return value if weight == 1.0 else weight * value

    def clock(self, rows: int) -> float:
        """Count ``rows`` more rows shaped; the weight of their term, from the rows shaped
        before them: 0 before ``start``, then 1, or with a ``stop`` 1 − rows/stop down
        to 0."""
        before = self.steps
        self.steps += rows
        if before < self.start:
            return 0.0
        if self.stop:
            return max(0.0, 1.0 - before / self.stop)
        return 1.0

    def values(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        episode: np.ndarray,
        t: np.ndarray,
        step_rows: int,
    ) -> np.ndarray:
        """−β·D (or −β·log(1 + D)) for rows (M,) of one or many steps of ``step_rows``
        copies each (M a multiple of it), whatever the start; same arguments as
        :meth:`reward`.

        The target rows are encoded in batches of :func:`encode_batch_rows` rows (many
        steps' at once) where a step's copies are a multiple of 16, else a step's at a
        time: the row count that keeps each row's bits those of a one-step encode
        (source_cache.py), so a rollout's terms computed at once
        (:meth:`ShapedBatchedEnv.deferred_terms`) are the per-step terms to the bit."""
        x_t = np.concatenate([obs[:, self.robot_state_indices], action], 1)
        if x_t.shape[1] != self.model.target_dim:
            raise PvedError(
                f"target state-action has dim {x_t.shape[1]}, the model's target input is "
                f"{self.model.target_dim}"
            )
        # the source half is the bank's, encoded once per run in batches sized after
        # one step's rows, which keeps the per-step encode's bits (source_cache.py)
        q_s = self.encoded(step_rows).lookup(episode, t, self.time_scale)
        batch = encode_batch_rows(step_rows) if step_rows % MIN_BATCH_ROWS == 0 else step_rows
        x = torch.as_tensor(x_t, dtype=torch.float32)
        with torch.no_grad():
            parts = [self.model.shared_target(chunk) for chunk in x.split(batch)]
            q_t = SharedRep(
                torch.cat([p.mean for p in parts]),
                None if parts[0].logvar is None else torch.cat([p.logvar for p in parts]),  # type: ignore[misc]
            )
            distance = self.model.shaping_between(q_s, q_t)
        d = distance.double().numpy()
        if self.form == "log1p":
            d = np.log1p(d)
        # past the end of a source episode there is nothing to compare with: no term
        return np.where(self.covered(episode, t), -self.beta * d, 0.0)

    def covered(self, episode: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether target steps ``t`` (N,) of bank episodes ``episode`` (N,) meet a step
        the source took, bool (N,) (:func:`pved.transfer.source_bank.source_covered`)."""
        return source_covered(t, self.bank.lengths[episode], self.time_scale)

    def encoded(self, call_rows: int) -> EncodedBank:
        """The bank's source posteriors, encoded at the first call in batches sized after
        ``call_rows``, the rows a step shapes (source_cache.py)."""
        if self._encoded is None or self._encoded.bank is not self.bank:
            rows = encode_batch_rows(call_rows)
            self._encoded = encode_bank(self.model, self.bank, rows)
        return self._encoded

    def term(self, value: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """The reward term (N,) of one step from :meth:`reward`'s ``value`` (N,) at this
        step and ``previous`` (N,), the value at the same env copy's previous step (0 at
        an episode's first step): the value itself, or for the ``"potential"`` form
        Φ_t − Φ_{t−1}/γ."""
        if self.form != "potential":
            return value
        return value - previous / self.gamma


@dataclass
class _PendingStep:
    """One step's inputs to a deferred term (:meth:`ShapedBatchedEnv.deferred_terms`)."""

    obs: np.ndarray  # (N, obs_dim) the observations the step was taken from
    encoded: np.ndarray | None  # (N, act_dim) the actions encoded; None: no term (a guide form)
    episode: np.ndarray  # (N,) bank episodes
    t: np.ndarray  # (N,) steps within them
    weight: float  # the term's weight (LatentShaping.clock): 0 before the start, after the stop
    done: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (N,)


class ShapedBatchedEnv(BatchedEnv):
    """A batched env whose reward carries the Eq. 10 shaping term."""

    def __init__(self, env: BatchedEnv, shaping: LatentShaping, match_keys: tuple[str, ...]):
        self.env = env
        self.shaping = shaping
        self.match_keys = match_keys
        self.num_envs = env.num_envs
        self.single_observation_space = env.single_observation_space
        self.single_action_space = env.single_action_space
        self.robot_state_indices = env.robot_state_indices
        self.max_episode_steps = env.max_episode_steps
        self._obs = np.zeros((self.num_envs, *env.single_observation_space.shape))
        self._t = np.zeros(self.num_envs, dtype=np.int64)
        self._episode = np.zeros(self.num_envs, dtype=np.int64)
        self._rng: np.random.Generator | None = None
        self._mean: np.ndarray | None = None
        # each copy's last value of LatentShaping.reward (the potential form's Φ_{t−1})
        self._previous = np.zeros(self.num_envs)
        self._guide: AlignGuide | PriorGuide | None = None
        # deferred terms (defer_terms): each step's inputs, kept until deferred_terms
        self._deferred = False
        self._pending: list[_PendingStep] = []

    def defer_terms(self) -> None:
        """From now on leave the term out of each step's reward and return the terms of
        the steps since the last call from :meth:`deferred_terms` (pved's PPO asks for
        them after each rollout): a rollout's target rows are then encoded in a few large
        batches instead of one small batch a step (``pved.rl.ppo``)."""
        self._deferred = True

    def deferred_terms(self) -> np.ndarray:
        """The terms (T, N) of the T steps since the last call, in order: to the bit what
        :meth:`step` would have added to their rewards (tests/test_shaping_cache.py)."""
        pending, self._pending = self._pending, []
        terms = np.zeros((len(pending), self.num_envs))
        shaped = [k for k, p in enumerate(pending) if p.encoded is not None and p.weight > 0.0]
        if shaped:
            n = self.num_envs
            values = self.shaping.values(
                np.concatenate([pending[k].obs for k in shaped]),
                np.concatenate([pending[k].encoded for k in shaped]),
                np.concatenate([pending[k].episode for k in shaped]),
                np.concatenate([pending[k].t for k in shaped]),
                n,
            ).reshape(len(shaped), n)
            for row, k in enumerate(shaped):
                w = pending[k].weight
                terms[k] = values[row] if w == 1.0 else w * values[row]
        if self.shaping.form in GUIDE_FORMS:
            return terms
        previous = self._previous
        for k, p in enumerate(pending):
            value = terms[k].copy()
            terms[k] = self.shaping.term(value, previous)
            previous = value
            previous[p.done] = 0.0
        self._previous = previous
        return terms

    @property
    def action_guide(self) -> AlignGuide | PriorGuide | None:
        """A guide form's loss on the mean action (:data:`GUIDE_FORMS`; PPO reads it;
        None for a reward form)."""
        if self.shaping.form not in GUIDE_FORMS:
            return None
        if self._guide is None:
            space = self.single_action_space
            guide = AlignGuide if self.shaping.form == "align" else PriorGuide
            self._guide = guide(self.shaping, space.low, space.high, self.num_envs)
        return self._guide

    def guide_context(self) -> np.ndarray | None:
        """The guide's context rows (N, ·) at the current observations: what the next
        :meth:`step` carries in ``info`` (the prior form's: the decoded prior action);
        None for a reward form. Read by ``pved prior-policy`` to act with the prior."""
        guide = self.action_guide
        return None if guide is None else guide.context(self._obs, self._episode, self._t)

    def set_mean_actions(self, mean: np.ndarray) -> None:
        """The policy's mean actions (N, act_dim) at the current observations, which the
        next :meth:`step` encodes when the shaping's action is ``"mean"``; pved's PPO
        calls it before every step."""
        self._mean = np.asarray(mean, dtype=np.float64).reshape(self.num_envs, -1)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        obs, info = self.env.reset(seed=seed, options=options)
        if seed is not None or self._rng is None:
            # draws bank episodes when the task has no parameters to match on
            self._rng = np.random.default_rng(seed)
        self._obs = obs
        self._t[:] = 0
        self._previous[:] = 0.0
        self._pending = []  # the steps before a reset are not part of any rollout
        params = task_params(info, self.match_keys, self.num_envs)
        self._episode = self.shaping.bank.match(params, self._rng)
        return obs, info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        actions = np.asarray(actions, dtype=np.float64)
        encoded = actions
        if self.shaping.action == "mean":
            if self._mean is None:
                raise PvedError(
                    "the shaping encodes the policy's mean action: call set_mean_actions "
                    "before each step, or build LatentShaping with action='taken'"
                )
            encoded = np.clip(
                self._mean, self.single_action_space.low, self.single_action_space.high
            )
            self._mean = None  # one step's mean, never reused for the next
        guide = self.action_guide
        context = None
        pending = None
        shaping = np.zeros(self.num_envs)
        if guide is not None:  # no reward term: the context of PPO's loss on the mean
            self.shaping.clock(self.num_envs)  # counted as shaped (a guide has no start)
            context = guide.context(self._obs, self._episode, self._t)
            if self._deferred:  # a step with no term: deferred_terms gives it 0
                pending = _PendingStep(self._obs, None, self._episode, self._t, weight=0.0)
        elif self._deferred:  # the term comes later, for the whole rollout at once
            weight = self.shaping.clock(self.num_envs)
            pending = _PendingStep(
                self._obs.copy(), encoded, self._episode.copy(), self._t.copy(), weight
            )
        else:
            value = self.shaping.reward(self._obs, encoded, self._episode, self._t)
            shaping = self.shaping.term(value, self._previous)
            self._previous = value.copy()  # never the returned term itself
        covered = self.shaping.covered(self._episode, self._t)
        obs, env_reward, terminated, truncated, info = self.env.step(actions)
        info = dict(info)
        if context is not None:
            info[GUIDE_CONTEXT] = context
            info[GUIDE_MASK] = covered  # PPO leaves the guide's rows past the source's end out
        info["env_reward"] = env_reward
        info[SOURCE_ENDED] = ~covered
        done = terminated | truncated
        if pending is not None:
            pending.done = np.asarray(done, dtype=bool).copy()
            self._pending.append(pending)
            reward = np.asarray(env_reward, dtype=np.float64)
        else:
            info["reward_shaping"] = shaping
            reward = env_reward + shaping
        self._t += 1
        if done.any():
            self._t[done] = 0
            if not self._deferred:
                self._previous[done] = 0.0
            params = task_params(info, self.match_keys, self.num_envs)
            self._episode[done] = self.shaping.bank.match(params[done], self._rng)
        self._obs = obs
        return obs, reward, terminated, truncated, info

    def state_dict(self) -> dict[str, Any] | None:
        """The wrapped env's :meth:`state_dict` with this wrapper's own (the last
        observation, each copy's step and bank episode, the generator that draws bank
        episodes), so a PPO checkpoint resumes the same shaped episodes; None when the
        wrapped env cannot save its state (PPO then starts fresh episodes on resume)."""
        save = getattr(self.env, "state_dict", None)
        if not callable(save):
            return None
        if self._pending:
            raise PvedError("the shaped env has deferred terms not yet taken: save after them")
        return {
            "env": save(),
            "obs": self._obs.copy(),
            "t": self._t.copy(),
            "episode": self._episode.copy(),
            "rng": None if self._rng is None else self._rng.bit_generator.state,
            "shaping_steps": self.shaping.steps,
            "previous": self._previous.copy(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict` of a wrapper built with the same arguments."""
        t = np.asarray(state["t"], dtype=np.int64)
        if t.shape != (self.num_envs,):  # checked first: a refused state changes nothing
            raise PvedError(f"shaped env state is for {t.shape} copies, not {self.num_envs}")
        self.env.load_state_dict(state["env"])  # type: ignore[attr-defined]
        self._obs = np.asarray(state["obs"], dtype=np.float64).copy()
        self._t = t.copy()
        self._episode = np.asarray(state["episode"], dtype=np.int64).copy()
        # states saved before the shaping start existed lack the clock; it only matters
        # with a start, which those runs did not have
        self.shaping.steps = int(state.get("shaping_steps", 0))
        # states saved before the potential form existed lack it; only that form reads it
        self._previous = np.asarray(
            state.get("previous", np.zeros(self.num_envs)), dtype=np.float64
        ).copy()
        self._rng = None
        if state["rng"] is not None:
            self._rng = np.random.default_rng()
            self._rng.bit_generator.state = state["rng"]

    def close(self) -> None:
        self.env.close()


class LatentShapingWrapper(
    gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray], gym.utils.RecordConstructorArgs
):
    """The Eq. 10 shaping as a plain Gymnasium wrapper around one target-task env.

    ``mean_action(obs) -> action`` gives the learner's mean (deterministic) action at an
    observation; the wrapper encodes it when the shaping's action is ``"mean"`` (the
    default), and the action taken when it is ``"taken"``.

    It records its constructor arguments (as Gymnasium's own wrappers do), so
    ``env.spec`` can rebuild the wrapped env, which Gymnasium's env checker relies on.
    """

    def __init__(
        self,
        env: gym.Env[np.ndarray, np.ndarray],
        shaping: LatentShaping,
        match_keys: tuple[str, ...],
        mean_action: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, shaping=shaping, match_keys=match_keys, mean_action=mean_action
        )
        gym.Wrapper.__init__(self, env)
        if shaping.form in GUIDE_FORMS:
            raise PvedError(
                f"the {shaping.form} form is a loss on the policy's mean action that pved's "
                "PPO adds; a Gymnasium wrapper can only change the reward (use ShapedBatchedEnv)"
            )
        if shaping.action == "mean" and mean_action is None:
            raise PvedError(
                "the shaping encodes the policy's mean action: give mean_action (e.g. "
                "lambda obs: model.predict(obs, deterministic=True)[0] for Stable-Baselines3), "
                "or build LatentShaping with action='taken'"
            )
        self.shaping = shaping
        self.match_keys = match_keys
        self.mean_action = mean_action
        self._obs: np.ndarray = np.zeros(env.observation_space.shape or ())
        self._t = 0
        self._episode = 0
        self._rng: np.random.Generator | None = None
        self._previous = 0.0  # the potential form's Φ_{t−1}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        self._obs = np.asarray(obs)
        self._t = 0
        self._previous = 0.0
        params = task_params(info, self.match_keys, 1)
        self._episode = int(self.shaping.bank.match(params, self._rng)[0])
        return obs, info

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        act = np.asarray(action, dtype=np.float64).reshape(1, -1)
        if self.shaping.action == "mean" and self.mean_action is not None:
            space = self.env.action_space
            act = np.clip(
                np.asarray(self.mean_action(self._obs), dtype=np.float64).reshape(1, -1),
                getattr(space, "low", -np.inf),
                getattr(space, "high", np.inf),
            )
        value = self.shaping.reward(
            self._obs[None], act, np.array([self._episode]), np.array([self._t])
        )
        shaping = float(self.shaping.term(value, np.array([self._previous]))[0])
        self._previous = float(value[0])
        obs, env_reward, terminated, truncated, info = self.env.step(action)
        info = dict(info)
        info["env_reward"] = float(env_reward)
        info["reward_shaping"] = shaping
        info[SOURCE_ENDED] = not bool(
            self.shaping.covered(np.array([self._episode]), np.array([self._t]))[0]
        )
        self._t += 1
        self._obs = np.asarray(obs)
        return obs, float(env_reward) + shaping, terminated, truncated, info
