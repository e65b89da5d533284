"""Registry of transfer methods: what each name trains the target agent with.

A method is a recipe, not a model: which shared-space model (if any) shapes the reward,
in which form, and on which reward the target trains. The paper's methods keep the
model's name (``pved``, its ablations, ``gupta2017``); the references are ``ppo`` and
``oracle``; a method beyond the paper gets a name of its own here, so ``pved protocol``,
``pved claims`` and ``pved compare`` treat it like the others (issue 51).

Adding a method = one :class:`Method` in :data:`METHODS`; its model is trained (and, in a
protocol, shared with every method that names the same model).
"""

from __future__ import annotations

from dataclasses import dataclass

from pved.errors import PvedError
from pved.models.registry import MODELS
from pved.transfer.shaping import SHAPING_FORMS

NO_TRANSFER = "ppo"  # the target agent's restricted reward alone
ORACLE = "oracle"  # the target agent with the source's full reward, no shaping
AA_REFERENCE = "ppo-aa"  # plain PPO again on other seeds: the A/A check's second set
REFERENCE_METHODS = (NO_TRANSFER, AA_REFERENCE, ORACLE)


@dataclass(frozen=True)
class Method:
    """One transfer method.

    Attributes:
        name: the name the CLI, protocols and reports use.
        model: the shared-space model whose shared codes shape the reward (a key of
            :data:`pved.models.MODELS`); None for a method with no shaping term.
        shaping_form: how the distance enters the reward (:data:`SHAPING_FORMS`).
        train_reward: the target task's reward the target trains on, ``"restricted"``
            (the target task as the paper sets it) or ``"full"`` (the oracle's).
        paper: whether the paper defines the method (the others go beyond it).
        summary: one line for ``--help`` and the docs.
        beta_grid: the protocol's β grid for the method where a pair sets none for it
            (None: the pair's common grid).
        anneal: the share of the run over which the shaping's weight falls linearly to
            0: the ``"align"`` form's loss (None: :data:`pved.transfer.align_guide.ALIGN_ANNEAL`)
            or a reward form's term (None: never, as in the paper).
    """

    name: str
    model: str | None
    shaping_form: str = "eq10"
    train_reward: str = "restricted"
    paper: bool = True
    summary: str = ""
    beta_grid: tuple[float, ...] | None = None
    anneal: float | None = None

    @property
    def shaped(self) -> bool:
        """Whether the method adds a shaping term (and so needs a model and a bank)."""
        return self.model is not None


def _paper_model_methods() -> dict[str, Method]:
    summaries = {
        "pved": "PVED's shared space, Eq. 10 (the paper's method)",
        "pved-state-only": "ablation: encoders see states only (paper IV.B)",
        "pved-shared-only": "ablation: no agent-specific space (paper IV.B)",
        "pved-det-shared": "ablation: deterministic shared space (paper IV.B)",
        "pved-vae": "ablation: a VAE per agent, shared prior (paper IV.B)",
        "gupta2017": "Gupta et al. 2017's invariant feature space (baseline)",
    }
    return {name: Method(name, name, summary=summaries.get(name, "")) for name in MODELS}


#: Method name -> recipe.
METHODS: dict[str, Method] = {
    **_paper_model_methods(),
    # Beyond the paper (docs/decisions/transfer.md, "A potential-based Eq. 10"): PVED's
    # distance as a potential, so the shaping's discounted sum over an episode is one
    # step's term, not one per step: the target cannot escape the term by ending its
    # episodes early, and the term no longer outweighs the task over a long episode.
    "pved-potential": Method(
        "pved-potential",
        "pved",
        shaping_form="potential",
        paper=False,
        summary="beyond the paper: PVED's Eq. 10 distance as a look-back potential",
        # a step pays β·(D_{t−1} − D_t) + β·D_{t−1}·(1/γ − 1), not β·D_t: for the same β
        # one to two orders of magnitude less than Eq. 10's term, so the grid sits a decade
        # higher (set before any run of the method; the protocol extends it at an edge)
        beta_grid=(1.0, 0.1, 0.01),
    ),
    # Beyond the paper (docs/decisions/transfer.md, "pved-align"): with the mean action
    # encoded, Eq. 10's term cannot steer the mean action through PPO's gradient; this
    # method pays no term and instead adds β·log(1 + D) to PPO's loss, differentiated
    # through the target encoder with respect to the mean action, annealed to 0 by half
    # the run (pved.transfer.align_guide.AlignGuide).
    "pved-align": Method(
        "pved-align",
        "pved",
        shaping_form="align",
        paper=False,
        summary="beyond the paper: PVED's distance as a loss on the mean action, annealed",
        # against PPO's loss on normalised advantages (order 0.01-0.1, its gradient order
        # 1): a weight of 1 lets the guide lead, 0.01 makes it a nudge (set before any run)
        beta_grid=(1.0, 0.1, 0.01),
    ),
    # The same with the guide gone by a quarter of the run, not half (docs/decisions/
    # transfer.md, "pved-align-short"): on reacher pved-align's success rose only once the
    # guide had faded, too late to reach PPO's final in half its steps.
    "pved-align-short": Method(
        "pved-align-short",
        "pved",
        shaping_form="align",
        paper=False,
        summary="beyond the paper: pved-align with the guide gone by a quarter of the run",
        beta_grid=(1.0, 0.1, 0.01),
        anneal=0.25,
    ),
    # Beyond the paper (docs/decisions/transfer.md, "pved-prior"): not a distance between
    # codes but the action PVED's c-only decoder p_θ'S (Eq. 8) gives at the source's code
    # of the matched moment; the mean action is pulled towards it, the weight annealed to
    # 0 by half the run as pved-align's (pved.transfer.prior_guide.PriorGuide).
    "pved-prior": Method(
        "pved-prior",
        "pved",
        shaping_form="prior",
        paper=False,
        summary="beyond the paper: the source's behaviour decoded into the target's action "
        "(Eq. 8) as a prior on the mean action, annealed",
        # set before any run: per row and action dim the loss's gradient on μ is
        # 2β·gap/(h²·A·B), a gap of order half a half-box (h) at the start; PPO's surrogate
        # gives μ about |adv|·|a − μ|/(σ²·B) ≈ 1/B with normalised advantages and σ ≈ 1.
        # On a 4-dim action β = 10 lets the prior lead (2.5/B), 1 gives a quarter of
        # PPO's pull and 0.1 a nudge; the grid sits a decade above pved-align's
        beta_grid=(10.0, 1.0, 0.1),
        anneal=0.5,
    ),
    # Beyond the paper (docs/decisions/transfer.md, "pved-anneal"): the paper's Eq. 10 term
    # with β falling linearly to 0 by half the run (issue 51's "β annealed to zero"). The
    # term guides while the target knows nothing, where it paid off (walker-hopper); the
    # second half is plain PPO, which can undo what a term that changes the optimal
    # policy taught (humanoid-ant's PVED walks half as far as PPO).
    "pved-anneal": Method(
        "pved-anneal",
        "pved",
        paper=False,
        summary="beyond the paper: Eq. 10 with beta annealed to 0 by half the run",
        anneal=0.5,
    ),
    NO_TRANSFER: Method(NO_TRANSFER, None, summary="PPO on the target task's reward alone"),
    # The A/A check (docs/decisions/claims.md): the same code and reward as ppo on a block
    # of seeds no other method uses (protocol_plan.reference_seed), so that ppo-aa − ppo,
    # 0 in truth, shows how large a difference the runs make by chance.
    AA_REFERENCE: Method(
        AA_REFERENCE,
        None,
        paper=False,
        summary="reference: plain PPO again on other seeds (the A/A check's second set)",
    ),
    ORACLE: Method(
        ORACLE, None, train_reward="full", summary="PPO on the source's full reward, no shaping"
    ),
}

for _method in METHODS.values():  # a typo in the table fails at import, not mid-protocol
    assert _method.shaping_form in SHAPING_FORMS, _method
    assert _method.model is None or _method.model in MODELS, _method
    # a potential's sum over an episode telescopes only if Φ stays one function
    assert _method.anneal is None or _method.shaping_form != "potential", _method
    assert _method.anneal is None or 0.0 < _method.anneal <= 1.0, _method


def get_method(name: str) -> Method:
    """The registered method ``name``; an unknown one raises :class:`PvedError` naming the
    known ones."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise PvedError(
            f"unknown method {name!r}; known methods: {', '.join(sorted(METHODS))}"
        ) from None


def shaped_methods() -> list[str]:
    """The names of the methods with a shaping term."""
    return [m.name for m in METHODS.values() if m.shaped]


__all__ = [
    "AA_REFERENCE",
    "METHODS",
    "NO_TRANSFER",
    "ORACLE",
    "REFERENCE_METHODS",
    "Method",
    "get_method",
    "shaped_methods",
]
