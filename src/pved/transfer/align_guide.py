"""The ``"align"`` shaping form: PVED's distance as a loss on the policy's mean action.

A method beyond the paper (``pved-align``, ``pved-align-short``; docs/decisions/transfer.md,
"pved-align"). Eq. 10 (:mod:`pved.transfer.shaping`) adds −β·D to the reward; this form
adds no reward term and instead gives PPO a loss on the mean action and its gradient
(:class:`pved.rl.guide.ActionGuide`), through the frozen target encoder of the same model
and against the same source codes (:class:`pved.transfer.shaping.LatentShaping`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch

from pved.errors import PvedError
from pved.models.base import SharedRep, SharedSpaceModel
from pved.models.numpy_distance import TargetDistance, numpy_distance_covers
from pved.transfer.source_cache import EncodedBank


class GuideSource(Protocol):
    """What the guide reads of :class:`pved.transfer.shaping.LatentShaping` (which builds
    the guide, so the guide names the shape it needs rather than importing it back)."""

    # read-only members, so any attribute of a compatible type satisfies them
    @property
    def model(self) -> SharedSpaceModel: ...
    @property
    def beta(self) -> float: ...
    @property
    def align_anneal(self) -> float: ...
    @property
    def time_scale(self) -> float: ...
    @property
    def robot_state_indices(self) -> np.ndarray: ...

    def encoded(self, call_rows: int) -> EncodedBank: ...


#: The D gate (docs/decisions/transfer.md, "A guide that cannot take PPO's budget"): a row
#: whose D exceeds :data:`D_GATE_FACTOR` times the :data:`D_GATE_QUANTILE` quantile of D
#: over the model's matched training pairs lies where the encoders saw no pair like it,
#: and its gradient says nothing the pairs taught: weight 0. A tenfold margin over the
#: 99th percentile leaves the matched pairs' own tail in (set before any run).
D_GATE_QUANTILE = 0.99
D_GATE_FACTOR = 10.0
#: Matched training pairs the quantile is read on (seeded sample; the whole set if fewer).
D_GATE_ROWS = 20_000


def matched_distance_limit(
    model: SharedSpaceModel, x_s: np.ndarray, x_t: np.ndarray, seed: int = 0
) -> float:
    """The D gate's limit: :data:`D_GATE_FACTOR` × the :data:`D_GATE_QUANTILE` quantile of
    Eq. 10's D over :data:`D_GATE_ROWS` seeded rows of the model's training pairs
    (``x_s`` (M, D_S) time-matched with ``x_t`` (M, D_T), as the model was fitted on)."""
    if len(x_s) == 0 or len(x_s) != len(x_t):
        raise PvedError(f"the D gate needs matched pairs, got {len(x_s)} and {len(x_t)} rows")
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(x_s), size=min(D_GATE_ROWS, len(x_s)), replace=False))
    parts = []
    with torch.no_grad():
        for rows in np.array_split(pick, max(1, -(-len(pick) // 4096))):
            source = torch.as_tensor(x_s[rows], dtype=torch.float32)
            target = torch.as_tensor(x_t[rows], dtype=torch.float32)
            parts.append(model.eval().shaping(source, target).double().numpy())
    return D_GATE_FACTOR * float(np.quantile(np.concatenate(parts), D_GATE_QUANTILE))


#: The share of a run's env steps over which the ``"align"`` form's weight falls from β to
#: 0 (linearly) unless a method sets its own (``Method.anneal``): the second half of
#: the run is plain PPO, which can undo what a wrong guide taught (set before any run of
#: the form).
ALIGN_ANNEAL = 0.5


class AlignGuide:
    """The ``"align"`` form: PVED's distance as a loss on the policy's mean action
    (:class:`pved.rl.guide.ActionGuide`; a method beyond the paper, ``pved-align``).

    With the mean action encoded, Eq. 10's term is a function of the state and of the
    policy, not of the sampled action, so PPO's likelihood-ratio gradient cannot move the
    mean action towards the source's code where the agent is (``pved.rl.guide``). This
    form pays no reward term; it adds to PPO's loss, at every minibatch row,

        w · log(1 + D(q_φS(c | x_S,t), q_φT(c | s_T,t, clip(μ_θ(s_T,t))))),
        w = β · max(0, 1 − progress / anneal),

    and passes its gradient with respect to μ_θ through the (frozen) target encoder. The
    log bounds the gradient where D is thousands of nats (jaco-fetch) and keeps it D's
    own where D is small; the weight falls to 0 by ``anneal`` of the run
    (``LatentShaping.align_anneal``, :data:`ALIGN_ANNEAL` unless the method sets its
    own), so the policy the run ends with answers to the task reward alone.

    A context row is the target's robot state at the step, then the source's posterior
    mean (K) and, for a stochastic model, its log-variance (K).

    With :attr:`d_limit` set (:func:`matched_distance_limit`, the transfer stage sets it)
    a row whose D exceeds it weighs 0 (the D gate); :attr:`last_stats` says what share of
    the last call's rows it left out, and the weight.
    """

    def __init__(
        self, shaping: GuideSource, low: np.ndarray, high: np.ndarray, num_envs: int
    ) -> None:
        self.shaping = shaping
        self.low = torch.as_tensor(np.asarray(low, dtype=np.float32))
        self.high = torch.as_tensor(np.asarray(high, dtype=np.float32))
        encoded = shaping.encoded(num_envs)
        self.state_dim = len(shaping.robot_state_indices)
        self.code_dim = int(encoded.mean.shape[-1])
        self.stochastic = encoded.logvar is not None
        self.context_dim = self.state_dim + self.code_dim * (2 if self.stochastic else 1)
        # the same loss in numpy where the model allows (pved.models.numpy_distance: a
        # quarter of autograd's cost at PPO's minibatch size); autograd otherwise
        model = shaping.model
        self.distance: TargetDistance | None = (
            TargetDistance(model) if self.stochastic and numpy_distance_covers(model) else None
        )
        self.low_np = self.low.numpy()
        self.high_np = self.high.numpy()
        # True once PPO has asked for the loss where its weight is 0: the weight never
        # rises again as the run goes on, so the context rows are not read from then on
        # and :meth:`context` gives zeros instead of looking them up (a resumed run looks
        # them up until its first update: the same numbers, a little later)
        self.faded = False
        # the D gate's limit (None: no gate), and what the last loss_grad call saw
        self.d_limit: float | None = None
        self.last_stats: dict[str, float] = {}
        # what PPO's reward gate judges an episode by and how far it must rise
        # (pved.rl.guide.RewardGate; set by the transfer stage from the run's config)
        self.gate_score: str | None = None
        self.gate_min_gap = 0.0

    @property
    def backend(self) -> str:
        """How the loss is computed: ``"numpy"`` or ``"torch"`` (autograd); the two differ
        in rounding only, so a run records it (its result) rather than hashing it."""
        return "numpy" if self.distance is not None else "torch"

    def context(self, obs: np.ndarray, episode: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Context rows (N, context_dim) float32 for target observations (N, obs_dim) at
        steps ``t`` (N,) of bank episodes ``episode`` (N,); zeros once :attr:`faded`."""
        if self.faded:
            return np.zeros((len(obs), self.context_dim), dtype=np.float32)
        sh = self.shaping
        q_s = sh.encoded(len(obs)).lookup(episode, t, sh.time_scale)
        parts = [obs[:, sh.robot_state_indices].astype(np.float32), q_s.mean.numpy()]
        if q_s.logvar is not None:
            parts.append(q_s.logvar.numpy())
        return np.concatenate(parts, 1)

    def weight(self, progress: float) -> float:
        """β · max(0, 1 − progress / anneal)."""
        return self.shaping.beta * max(0.0, 1.0 - float(progress) / self.shaping.align_anneal)

    def loss_grad(
        self, context: np.ndarray, mean: np.ndarray, progress: float
    ) -> tuple[float, np.ndarray]:
        """w · mean over rows of log(1 + D) and its gradient (B, A) w.r.t. ``mean``;
        where w is 0 the guide is :attr:`faded` from then on."""
        w = self.weight(progress)
        self.last_stats = {"weight": w, "d_masked": 0.0}
        if w == 0.0:
            self.faded = True
            return 0.0, np.zeros_like(mean, dtype=np.float32)
        if self.distance is not None:
            return self._loss_grad_numpy(context, mean, w)
        return self._loss_grad_torch(context, mean, w)

    def _loss_grad_numpy(
        self, context: np.ndarray, mean: np.ndarray, w: float
    ) -> tuple[float, np.ndarray]:
        """:meth:`loss_grad` through :class:`TargetDistance` (the weight ``w`` > 0)."""
        assert self.distance is not None
        ctx = np.asarray(context, dtype=np.float32)
        mu = np.asarray(mean, dtype=np.float32)
        s, k = self.state_dim, self.code_dim
        clipped = np.clip(mu, self.low_np, self.high_np)
        x_t = np.concatenate([ctx[:, :s], clipped], 1)
        distance, done = self.distance.forward(ctx[:, s : s + k], ctx[:, s + k :], x_t)
        kept = self._d_gate(distance)
        loss = w * float((np.log1p(distance) * kept).mean(dtype=np.float64))
        d_distance = np.float32(w / len(mu)) / (np.float32(1.0) + distance) * kept
        grad = self.distance.input_grad(done, d_distance)[:, s:]
        # torch.clamp's gradient: 1 inside the box, bounds included, 0 outside
        grad *= clipped == mu
        return loss, grad

    def _loss_grad_torch(
        self, context: np.ndarray, mean: np.ndarray, w: float
    ) -> tuple[float, np.ndarray]:
        """:meth:`loss_grad` by autograd, for any model (the weight ``w`` > 0)."""
        ctx = torch.as_tensor(np.asarray(context, dtype=np.float32))
        s, k = self.state_dim, self.code_dim
        q_s = SharedRep(ctx[:, s : s + k], ctx[:, s + k :] if self.stochastic else None)
        mu = torch.as_tensor(np.asarray(mean, dtype=np.float32)).requires_grad_(True)
        # the encoders saw clipped mean actions; outside the box the gradient is 0
        x_t = torch.cat([ctx[:, :s], torch.clamp(mu, self.low, self.high)], 1)
        model = self.shaping.model
        distance = model.shaping_between(q_s, model.shared_target(x_t))
        kept = torch.from_numpy(self._d_gate(distance.detach().numpy()))
        loss = w * (torch.log1p(distance) * kept).mean()
        (grad,) = torch.autograd.grad(loss, mu)  # the model's own parameters stay untouched
        return float(loss.detach()), grad.numpy()

    def _d_gate(self, distance: np.ndarray) -> np.ndarray:
        """Row weights (B,) float32 of the D gate, 1 where D is within :attr:`d_limit` (all
        without a limit); records the share left out in :attr:`last_stats`."""
        if self.d_limit is None:
            return np.ones(len(distance), dtype=np.float32)
        kept = np.asarray(distance, dtype=np.float64) <= self.d_limit
        self.last_stats["d_masked"] = 1.0 - float(kept.mean())
        return kept.astype(np.float32)


__all__ = [
    "ALIGN_ANNEAL",
    "D_GATE_FACTOR",
    "D_GATE_QUANTILE",
    "D_GATE_ROWS",
    "AlignGuide",
    "GuideSource",
    "matched_distance_limit",
]
