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
minibatch step, back-propagates the guide's gradient with respect to the actor's mean
into a parameter gradient of its own. Kept in ``rl`` as a protocol so that PPO imports
nothing from the transfer stage above it.

A guide must not take PPO's budget. PPO clips its own gradient (actor, critic and
log-std together) to one global norm; a guide's gradient added before that clip would
shrink PPO's share of it the stronger the guide. So PPO clips its own gradient exactly as
without a guide, then adds the guide's parameter gradient scaled to a norm of at most
:data:`GUIDE_GRAD_RATIO` times the clipped one's (docs/decisions/transfer.md, "A guide
that cannot take PPO's budget"). And :class:`RewardGate` turns the guide off for the
rest of a run once the task is being found: from then on the task reward leads alone.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pved.errors import PvedError

#: The key of the per-step context rows (N, K) in a guided env's ``info``.
GUIDE_CONTEXT = "guide_context"
#: The key of a guided env's optional per-step row weights (N,) (bool or 0/1) in ``info``:
#: a row of weight 0 has nothing to compare with (a target step past its source episode's
#: end); PPO leaves it out of the guide's loss, where it counts as 0 in the mean over rows.
GUIDE_MASK = "guide_mask"

#: ρ: at each minibatch the guide's parameter gradient is scaled to a norm of at most ρ
#: times PPO's own clipped gradient's, then added. 1 lets a guide steer as hard as the
#: task's advantage does and never harder (set before any run; docs/decisions/transfer.md).
GUIDE_GRAD_RATIO = 1.0
#: The reward gate's window: its start is the run's first this many finished episodes,
#: its recent window the last this many after them.
GATE_EPISODES = 50
#: The reward gate closes once the recent window's mean score beats the start's by this
#: many standard errors (Welch's t): about one chance in a million per look were the two
#: windows drawn alike (set before any run; docs/decisions/transfer.md).
GATE_Z = 5.0


@runtime_checkable
class ActionGuide(Protocol):
    """A differentiable loss on the policy's mean actions, added to PPO's.

    A guide may also keep, in an attribute ``last_stats`` (a dict of floats), what its
    last :meth:`loss_grad` call saw (e.g. the share of rows it masked); PPO records it as
    ``loss/guide_<key>``; and in attributes ``gate_score`` (a str) and ``gate_min_gap`` (a
    float) what its :class:`RewardGate` judges an episode by and how far that must rise.
    None of them is part of the protocol, so a guide without them is one.
    """

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


#: The scores a reward gate can judge an episode by, besides an ``info`` entry read at
#: the episode's last step: its success (``info["is_success"]``), its return on the env's
#: reward, its length, whether it ran to the time limit without terminating (PPO passes
#: that as the values); and ``"never"``: a gate that never closes.
GATE_SCORES = ("is_success", "return", "length", "completed", "never")


class RewardGate:
    """Turns a guide off for the rest of a run once the task is being found.

    ``score`` names what an episode is judged by: the pair's own measure of the task
    (``pved.experiments.transfer_spec.gate_score``), ``"is_success"``, ``"return"``,
    ``"length"`` or an ``info`` entry read at the episode's last step (``"x_position"``
    on humanoid-ant: how far the body got); ``"never"`` keeps the guide on (where the
    target's reward does not measure the task, so there is nothing to hand over to).
    None, for a guide whose caller names no measure, scores success where the env
    reports it and else the reward per step (return / length). That fallback rises when
    a body merely lasts longer (a Hopper's healthy reward is 0 on its last step, so a
    14-step episode earns 13/14 of the healthy term a step and a 24-step one 23/24): on
    walker-hopper it closed every guided run's gate within 8k steps of 300k, before the
    task's measure had moved.

    The first :data:`GATE_EPISODES` finished episodes are the run's start; once as many
    more have finished, each update compares the last :data:`GATE_EPISODES` with the
    start by Welch's t, and the gate closes for good once t exceeds :data:`GATE_Z` and
    the recent mean is at least ``min_gap`` above the start's. Two windows of 50 drawn
    alike give t > 5 about one time in a million, so noise does not close it; a success
    rate that rises from 0 closes it at about a third of the recent episodes succeeding.
    ``min_gap`` is for a score without a natural scale: a Hopper that falls at once ends
    within a few cm of its start, so t alone calls 14 cm found (on walker-hopper, at 8k
    steps); the pair's metric resolution (0.5 m there) says how far is more than a body
    falling a little further forward.
    """

    def __init__(
        self,
        episodes: int = GATE_EPISODES,
        z: float = GATE_Z,
        score: str | None = None,
        min_gap: float = 0.0,
    ) -> None:
        if episodes < 2 or not z > 0:
            raise PvedError(f"a reward gate needs >= 2 episodes and z > 0, got {episodes}, {z}")
        if score is not None and (not isinstance(score, str) or not score):
            raise PvedError(f"a reward gate's score must be a non-empty name, got {score!r}")
        if not (math.isfinite(min_gap) and min_gap >= 0):
            raise PvedError(f"a reward gate's min_gap must be finite and >= 0, got {min_gap}")
        self.episodes, self.z = int(episodes), float(z)
        self.score, self.min_gap = score, float(min_gap)
        # what the episodes are scored by, fixed at first sight: the score's name, or for
        # score None "success" or "reward_per_step"
        self.kind: str | None = None
        self.start: list[float] = []
        self.recent: list[float] = []
        self.t: float | None = None  # the last comparison's t
        self.closed_at: int | None = None  # the env step it closed at

    @property
    def info_key(self) -> str | None:
        """The ``info`` entry PPO reads at each finished episode's last step for this gate
        (None: the gate needs none; PPO then passes whether each episode completed)."""
        return self.score if self.score not in (None, *GATE_SCORES) else None

    @property
    def open(self) -> bool:
        """Whether the guide still acts."""
        return self.closed_at is None

    def observe(
        self,
        returns: list[float],
        lengths: list[float],
        successes: list[float],
        step: int,
        values: list[float] | None = None,
    ) -> None:
        """Take one update's finished episodes seen by env step ``step``: their returns,
        lengths, successes (where the env reports them) and ``values``: the
        :attr:`info_key` entry at each one's last step, or for ``"completed"`` whether it
        ran to the time limit; close the gate where the task is found."""
        if not self.open or not returns or self.score == "never":
            return
        scores = self._scores(returns, lengths, successes, values)
        for score in scores:
            if len(self.start) < self.episodes:
                self.start.append(score)
            else:
                self.recent.append(score)
        self.recent = self.recent[-self.episodes :]
        if len(self.recent) < self.episodes:
            return
        a, b = np.asarray(self.start), np.asarray(self.recent)
        gap = float(b.mean() - a.mean())
        se = math.sqrt(float(a.var(ddof=1) + b.var(ddof=1)) / self.episodes)
        self.t = gap / se if se > 0 else (math.inf if gap > 0 else 0.0)
        if self.t > self.z and gap >= self.min_gap:
            self.closed_at = int(step)

    def _scores(
        self,
        returns: list[float],
        lengths: list[float],
        successes: list[float],
        values: list[float] | None,
    ) -> list[float]:
        """Each finished episode's score by :attr:`score`."""
        if self.score is None:
            if self.kind is None:
                self.kind = "success" if len(successes) == len(returns) else "reward_per_step"
            if self.kind == "success":
                return [float(x) for x in successes]
            return [float(r) / max(float(n), 1.0) for r, n in zip(returns, lengths, strict=True)]
        self.kind = self.score
        by_name = {"is_success": successes, "return": returns, "length": lengths}
        got = by_name.get(self.score, values)  # "completed" or an info entry
        if got is None or len(got) != len(returns):
            raise PvedError(
                f"the reward gate scores episodes by {self.score!r}, which the env did not "
                f"report for every finished episode"
            )
        return [float(x) for x in got]

    def scalars(self) -> dict[str, float]:
        """What a run's metrics record of the gate at an update."""
        out = {"guide/gate_open": float(self.open)}
        if self.start:
            out["guide/gate_start"] = float(np.mean(self.start))
        if self.recent:
            out["guide/gate_recent"] = float(np.mean(self.recent))
        if self.t is not None and math.isfinite(self.t):
            out["guide/gate_t"] = self.t
        return out

    def state_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "start": list(self.start),
            "recent": list(self.recent),
            "t": self.t,
            "closed_at": self.closed_at,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        fits = (self.score,) if self.score is not None else ("success", "reward_per_step")
        if state["kind"] not in (None, *fits):
            raise PvedError(
                f"a reward gate scoring by {self.score!r} cannot resume one that scored by "
                f"{state['kind']!r}"
            )
        self.kind = state["kind"]
        self.start = [float(x) for x in state["start"]]
        self.recent = [float(x) for x in state["recent"]]
        self.t = None if state["t"] is None else float(state["t"])
        self.closed_at = None if state["closed_at"] is None else int(state["closed_at"])


__all__ = [
    "GATE_EPISODES",
    "GATE_SCORES",
    "GATE_Z",
    "GUIDE_CONTEXT",
    "GUIDE_GRAD_RATIO",
    "GUIDE_MASK",
    "ActionGuide",
    "RewardGate",
]
