"""The ``"prior"`` shaping form: the source's behaviour, decoded into the target's action.

A method beyond the paper (``pved-prior``; docs/decisions/transfer.md, "pved-prior").
The ``"align"`` form (:mod:`pved.transfer.align_guide`) pulls the policy's mean action
along the gradient of a distance between shared codes: it says "be nearer the source's
code", and the encoder's gradient may point anywhere the code is flat. PVED also has a
decoder from the shared code alone to the target's state-action, p_θ'S(s_T, a_T | c)
(Eq. 8), trained on the target's own code and, through Eq. 7's consistency, on codes the
source's encoder gives its paired rows. Applied to the source's code at the matched
moment it names an action: the one the model pairs with what the source does there.
This form pulls the mean action towards that action, with a weight that fades.

The decoder reads the bank row's code only, so the whole bank is decoded once, when the
guide is built, and looked up per step as the codes are.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.models.pved import PVED
from pved.transfer.align_guide import GuideSource

#: Bank rows decoded per batch (the decoder is three small layers: memory, not time).
DECODE_ROWS = 4096


def check_prior_model(model: type[SharedSpaceModel]) -> None:
    """Refuse, in one line, a model class whose c-only decoder cannot give the target's
    action: one that does not provide :meth:`PVED.decode_target_shared` (Eq. 8's p_θ'S;
    Gupta's model has no such decoder, and the point-code variant is not wired to it),
    or one whose decoders see only states."""
    if not issubclass(model, PVED):
        raise PvedError(
            f"the prior form decodes the target's action from the source's shared code "
            f"(PVED.decode_target_shared, Eq. 8's p_θ'S); model {model.name!r} does not "
            "provide it"
        )
    if model.states_only:
        raise PvedError(
            f"the prior form decodes the target's action from the source's shared code; "
            f"model {model.name!r} decodes the target's state only"
        )


def prior_actions(model: PVED, codes: np.ndarray) -> np.ndarray:
    """The action part of p_θ'S(x_T | c)'s mean at shared codes ``codes`` (..., C), in the
    target's raw action units (the model undoes its own standardisation): (..., A)
    float32, not clipped."""
    flat = torch.as_tensor(np.asarray(codes, dtype=np.float32)).reshape(-1, codes.shape[-1])
    parts = [model.decode_target_shared(batch) for batch in flat.split(DECODE_ROWS)]
    actions = torch.cat(parts)[:, model.target_state_dim :].numpy()
    return actions.reshape(*codes.shape[:-1], -1)


class PriorGuide:
    """The ``"prior"`` form: the mean action pulled towards the source's behaviour decoded
    into the target's action space (:class:`pved.rl.guide.ActionGuide`; ``pved-prior``).

    A context row is a_prior, the action part of p_θ'S(x_T | c)'s mean (Eq. 8's c-only
    decoder) at the mean of the source's shared posterior q_φS(c | s_S, a_S) of the bank
    row matched to the step (the align form's lookup and time base), in raw units,
    clipped to the target's action box. At a minibatch PPO's loss gains

        w · mean over rows of ‖(μ_θ(s_T) − a_prior) / h‖² / A,
        w = β · max(0, 1 − progress / anneal),

    with h the box's half-widths and A the action dim: per dimension a squared gap in
    half-boxes, the same scale on every pair. μ is not clipped: a mean outside the box
    is pulled back towards the prior, which lies inside (the align form's gradient is 0
    there). The weight falls to 0 by ``anneal`` of the run (``LatentShaping.align_anneal``)
    so the policy the run ends with answers to the task reward alone.
    """

    def __init__(
        self, shaping: GuideSource, low: np.ndarray, high: np.ndarray, num_envs: int
    ) -> None:
        model = shaping.model
        check_prior_model(type(model))
        assert isinstance(model, PVED)  # check_prior_model's promise, for the type checker
        self.shaping = shaping
        self.low = np.asarray(low, dtype=np.float32).reshape(-1)
        self.high = np.asarray(high, dtype=np.float32).reshape(-1)
        if not (np.isfinite(self.low).all() and np.isfinite(self.high).all()):
            raise PvedError("the prior form needs a bounded action box: it measures in half-boxes")
        if len(self.low) != model.dims.target_action_dim:
            raise PvedError(
                f"the target's action box has {len(self.low)} dims, the model's target "
                f"action {model.dims.target_action_dim}"
            )
        self.half_width = (self.high - self.low) / np.float32(2.0)
        self.context_dim = len(self.low)
        encoded = shaping.encoded(num_envs)
        # the decoded prior of every bank row, indexed as its codes are, so the step's
        # row comes from the align form's own lookup (whatever its rule at an episode's end)
        prior = np.clip(prior_actions(model, encoded.mean), self.low, self.high)
        self.decoded = dataclasses.replace(encoded, mean=prior, logvar=None)
        # True once PPO has asked for the loss where its weight is 0 (as AlignGuide.faded):
        # the weight never rises again, so the context is zeros from then on
        self.faded = False
        # what PPO's reward gate judges an episode by and how far it must rise
        # (pved.rl.guide.RewardGate; set by the transfer stage from the run's config)
        self.gate_score: str | None = None
        self.gate_min_gap = 0.0

    def context(self, obs: np.ndarray, episode: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Context rows (N, A) float32, a_prior for target steps ``t`` (N,) of bank
        episodes ``episode`` (N,) (``obs`` sets N); zeros once :attr:`faded`."""
        if self.faded:
            return np.zeros((len(obs), self.context_dim), dtype=np.float32)
        rows = self.decoded.lookup(episode, t, self.shaping.time_scale).mean
        return rows.numpy().astype(np.float32, copy=True)

    def weight(self, progress: float) -> float:
        """β · max(0, 1 − progress / anneal)."""
        return self.shaping.beta * max(0.0, 1.0 - float(progress) / self.shaping.align_anneal)

    def loss_grad(
        self, context: np.ndarray, mean: np.ndarray, progress: float
    ) -> tuple[float, np.ndarray]:
        """w · mean over rows of ‖(μ − a_prior)/h‖² / A and its gradient (B, A) w.r.t.
        ``mean``; where w is 0 the guide is :attr:`faded` from then on."""
        mu = np.asarray(mean, dtype=np.float32)
        prior = np.asarray(context, dtype=np.float32)
        if prior.shape != mu.shape or mu.ndim != 2 or mu.shape[1] != self.context_dim:
            raise PvedError(
                f"the prior guide takes (B, {self.context_dim}) context and mean rows, "
                f"got {prior.shape} and {mu.shape}"
            )
        w = self.weight(progress)
        if w == 0.0:
            self.faded = True
            return 0.0, np.zeros_like(mu)
        rows, dims = mu.shape
        gap = (mu - prior) / self.half_width
        loss = w * float(np.square(gap, dtype=np.float64).sum(1).mean()) / dims
        grad = np.float32(2.0 * w / (rows * dims)) * gap / self.half_width
        return loss, grad.astype(np.float32, copy=False)


__all__ = ["DECODE_ROWS", "PriorGuide", "check_prior_model", "prior_actions"]
