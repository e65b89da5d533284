"""An auxiliary loss on the policy's mean action, for a method beyond the paper.

PPO credits a reward to the *sampled* action through the likelihood ratio. A reward that
depends on the policy's *mean* action at the state (as Eq. 10's term does when it encodes
the mean action, ``pved.transfer.shaping``) is, to PPO's gradient, a reward of the state
alone: the policy can only lower it by visiting other states, never by choosing another
mean action where it is. A learner that should move its mean action towards what a
differentiable model prefers needs that model's gradient with respect to the action.

:class:`ActionGuide` is that hook. An env that offers one (attribute ``action_guide``,
not None) puts a context row per copy in ``info["guide_context"]`` at every step (what
the loss needs besides the action: for ``pved-align`` the target's robot state and the
source's shared code at that moment); PPO stores it beside the step and, at each
minibatch step, adds the guide's gradient with respect to the actor's mean to the
clipped-surrogate loss's. Kept in ``rl`` as a protocol so that PPO imports nothing from
the transfer stage above it.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

#: The key of the per-step context rows (N, K) in a guided env's ``info``.
GUIDE_CONTEXT = "guide_context"


@runtime_checkable
class ActionGuide(Protocol):
    """A differentiable loss on the policy's mean actions, added to PPO's."""

    #: columns of one context row (the K of ``info["guide_context"]``)
    context_dim: int

    def loss_grad(
        self, context: np.ndarray, mean: np.ndarray, progress: float
    ) -> tuple[float, np.ndarray]:
        """The loss and its gradient with respect to ``mean``.

        Args:
            context: (B, K) float32, the rows the env gave at the minibatch's steps.
            mean: (B, A) float32, the actor's mean actions at those steps' observations.
            progress: the share of the run's env steps done so far, in [0, 1] (a guide
                may weigh itself by it).

        Returns:
            (loss: float, dL/dmean: (B, A) float32); the loss is a mean over the B rows.
        """
        ...


__all__ = ["GUIDE_CONTEXT", "ActionGuide"]
