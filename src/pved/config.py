"""Typed configs: one preset per agent pair, holding the paper's Table 1 values.

A preset composes the configs of every stage (policies, pairing, model, transfer,
evaluation) so that ``pved <verb> --pair reacher`` needs no other argument. Presets are
read from pair spec files (:mod:`pved.spec`; the four built-in pairs' in
``pved/pairs/``). Stage configs are frozen dataclasses; overriding a field is
``dataclasses.replace``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from pved.checks import check_int, check_number, check_seed
from pved.errors import OptionError, PvedError
from pved.models.base import ModelConfig
from pved.models.pved import PVEDConfig
from pved.models.registry import model_class
from pved.pairing.align import ALIGNMENTS
from pved.rl.ppo import PPOConfig

# Seeds of the paper's protocol (IV.A): tuning and evaluation seeds of the DRL stage.
TUNING_SEEDS: tuple[int, ...] = (2000, 4000, 6000, 8000, 10000)
EVALUATION_SEEDS: tuple[int, ...] = (20000, 40000, 60000, 80000, 100000)
#: The ``paper-wide`` budget's evaluation seeds: the paper's five, then 22 more on the
#: same spacing (27 x 3 source policies = 81 runs a method).
WIDE_EVALUATION_SEEDS: tuple[int, ...] = tuple(20000 * k for k in range(1, 28))
#: The ``screen`` budget's evaluation seeds: disjoint from every evaluation seed above and
#: from the seeds s+1, s+2 the references run a source-less seed s as, so that choosing a
#: method on a screen never looks at the runs the paper's budget later judges (issue 64).
SCREEN_SEEDS: tuple[int, ...] = (11000, 13000, 15000, 17000, 19000)


@dataclass(frozen=True)
class PairingConfig:
    """How paired trajectories are collected on the training task (paper IV.A)."""

    episodes: int = 1000
    num_envs: int = 16
    align: str = "subsample"
    deterministic: bool = True  # the policies' mean actions: the control they learned
    seed: int = 0
    # ``align="dtw"`` (Gupta et al. 2017): rounds of (train ``dtw_model`` on the current
    # alignment, re-align every episode pair by DTW on its shared means), starting from
    # the subsampled alignment; ``dtw_epochs`` overrides the model's epochs per round.
    dtw_rounds: int = 2
    dtw_model: str = "pved"
    dtw_epochs: int | None = None

    def __post_init__(self) -> None:
        # every value checked here, before a collection starts (checks.py); the message
        # of an unknown alignment is the one users have always read
        check_int("episodes", self.episodes, low=1)
        check_int("num_envs", self.num_envs, low=1)
        if not isinstance(self.align, str) or self.align not in ALIGNMENTS:
            raise OptionError("align", self.align, "one of " + ", ".join(ALIGNMENTS))
        if not isinstance(self.deterministic, bool):
            raise OptionError("deterministic", self.deterministic, "true or false")
        check_seed("seed", self.seed)
        check_int("dtw_rounds", self.dtw_rounds, low=1)
        model_class(self.dtw_model)
        if self.dtw_epochs is not None:
            check_int("dtw_epochs", self.dtw_epochs, low=1)


@dataclass(frozen=True)
class TransferConfig:
    """PPO of the target agent on the target task with the Eq. 10 shaping term."""

    beta: float = 0.1
    bank_episodes: int = 200  # source rollouts on the target task to draw (s_S, a_S) from
    eval_every: int = 50_000  # env steps between evaluations (learning curve)
    eval_episodes: int = 100  # per evaluation point during training
    final_eval_episodes: int = 500  # the paper's success-rate measure
    ppo: PPOConfig = field(default_factory=PPOConfig)

    def __post_init__(self) -> None:
        # β weighs a non-negative distance: a negative β would reward moving away from
        # the source, and NaN would only surface as a NaN loss after a rollout; β = 0 is
        # Eq. 10 without its term
        check_number("beta", self.beta, low=0.0)
        check_int("bank_episodes", self.bank_episodes, low=1)
        check_int("eval_every", self.eval_every, low=0)
        check_int("eval_episodes", self.eval_episodes, low=1)
        check_int("final_eval_episodes", self.final_eval_episodes, low=1)
        if not isinstance(self.ppo, PPOConfig):
            raise OptionError("ppo", self.ppo, "a PPOConfig")


# The protocol's beta grid for the methods whose Eq. 10 term is the Euclidean distance
# between point codes (``pved-det-shared``; Gupta's alpha) rather than PVED's KL
# between Gaussians with learned variances. On walker-hopper their term started about
# three orders of magnitude smaller per unit of beta than PVED's (1,600 and 4,600
# times), and both stood still at every beta of the common grid; on reacher both chose
# its largest beta (docs/results.md). The common grid's values come first, so its runs
# stay candidates and complete ties go to them.
POINT_CODE_BETA_GRID: tuple[float, ...] = (0.1, 0.01, 0.001, 1.0, 10.0)


#: ``AgentEnv.policy`` values that name no file: the policy shipped with pved
#: (:mod:`pved.pretrained`), or the pair's own ``pved train-policy`` run (seed 0).
PRETRAINED = "pretrained"
TRAINED = "trained"


@dataclass(frozen=True)
class AgentEnv:
    """One agent's environment on one task of a pair, and the policy it acts with there.

    Attributes:
        agent, task: the names run directories and files are kept under.
        env_id: a Gymnasium id (``pved/...``, a stock one, or ``module:EnvId``).
        kwargs: ``gymnasium.make`` arguments, as (name, value) pairs in name order.
        policy: ``PRETRAINED``, ``TRAINED``, or the path of a policy file.
    """

    agent: str
    task: str
    env_id: str
    kwargs: tuple[tuple[str, Any], ...] = ()
    policy: str = PRETRAINED


@dataclass(frozen=True)
class PairPreset:
    """Everything that defines one agent pair's experiment (read from a pair spec file,
    ``pved.spec``)."""

    name: str
    source_agent: str
    target_agent: str
    training_task: str
    target_task: str
    model: PVEDConfig
    transfer: TransferConfig
    pairing: PairingConfig = field(default_factory=PairingConfig)
    # Task parameters both agents share in a paired training-task episode (paper IV.A),
    # and those a target-task episode is matched to a source bank episode on.
    shared_task_keys: tuple[str, ...] = ("target",)
    bank_match_keys: tuple[str, ...] = ("button_start",)
    # The paper's performance measure on the target task (IV.A): a key of
    # ``evaluate_policy``'s result, computed from the ``info`` entries ``eval_info_keys``.
    metric: str = "success_rate"
    # The protocol's tuning compares mean scores rounded to a multiple of this (None:
    # as they are): below it, a difference between tuning candidates is noise, and the
    # tie goes to the mean final return.
    metric_resolution: float | None = None
    eval_info_keys: tuple[str, ...] = ()
    # Whether the target's training reward measures the task (False on walker-hopper: the
    # Hopper's reward has no forward term, paper IV.A). A guide's reward gate hands the
    # run over to PPO's reward once the task is found only where it does: elsewhere that
    # reward could not hold what the guide taught (pved.experiments.transfer_spec.gate_score).
    metric_in_target_reward: bool = True
    # PPO for the pretrained policies, per (agent, task); missing entries use ``policy``.
    policy: PPOConfig = field(default_factory=PPOConfig)
    policy_overrides: tuple[tuple[str, str, PPOConfig], ...] = ()
    # Policies of this pair keep the evaluation point with the best mean return rather
    # than the last one (PPO on the locomotion bodies oscillates between gaits that fall
    # and gaits that do not; docs/decisions.md), evaluated on ``policy_eval_episodes``.
    policy_keep_best: bool = False
    policy_eval_episodes: int = 100
    # Stop a policy's training once ``policy_stop_evaluations`` evaluations in a row have
    # ``completion_rate`` >= ``policy_stop_completion`` and the last of them raised the
    # mean return by less than ``policy_stop_gain`` (a fraction) over the one before
    # (None: train every step). The Humanoid's steps are dear on CPUs; a policy that
    # neither falls nor still improves (e.g. walks farther) has little left to gain, while
    # one that only learned to stand up still does (docs/decisions.md).
    policy_stop_completion: float | None = None
    policy_stop_evaluations: int = 2
    policy_stop_gain: float = 0.02
    # The protocol's grid for the shaping weight (beta of Eq. 10; Gupta's alpha), searched
    # on the tuning seeds (paper IV.A; the paper does not print its grid). Per-method
    # grids in ``method_beta_grids`` replace it for that method.
    beta_grid: tuple[float, ...] = (0.1, 0.01, 0.001)
    method_beta_grids: tuple[tuple[str, tuple[float, ...]], ...] = (
        ("pved-det-shared", POINT_CODE_BETA_GRID),
        ("gupta2017", POINT_CODE_BETA_GRID),
    )
    # Env steps of one transfer run under each protocol budget (see ``BUDGETS``).
    protocol_steps: tuple[tuple[str, int], ...] = (
        ("smoke", 8192),
        ("quick", 300_000),
        ("paper", 1_000_000),
    )
    # Each agent's env on each task (four entries; ``agent_env``), and the observation
    # indices of an agent's robot state where its env does not report them itself
    # (a stock Gymnasium env): (agent, indices).
    envs: tuple[AgentEnv, ...] = ()
    robot_state: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def model_config(self, name: str, **overrides: Any) -> ModelConfig:
        """The config of model ``name`` for this pair: every field it shares with the
        pair's PVED config (Table 1's α weights, lr, batch size, epochs...) taken from
        there, the rest its own defaults, then ``overrides`` (e.g. ``seed=1``)."""
        cls = model_class(name).config_class
        own = {f.name for f in dataclasses.fields(cls) if f.init}
        values = {
            f.name: getattr(self.model, f.name)
            for f in dataclasses.fields(self.model)
            if f.init and f.name in own
        }
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def beta_grid_for(self, method: str) -> tuple[float, ...]:
        """The beta values the protocol tries for ``method``."""
        return dict(self.method_beta_grids).get(method, self.beta_grid)

    def transfer_steps(self, budget: str) -> int:
        """Env steps of one transfer run under protocol ``budget``."""
        steps = dict(self.protocol_steps)
        if budget not in steps:
            raise PvedError(f"unknown budget {budget!r}; known budgets: {', '.join(steps)}")
        return steps[budget]

    def agent_env(self, agent: str, task: str) -> AgentEnv:
        """``agent``'s env on ``task``; :class:`PvedError` when the pair has none."""
        for entry in self.envs:
            if (entry.agent, entry.task) == (agent, task):
                return entry
        if agent not in (self.source_agent, self.target_agent):
            kind, value, known = "agent", agent, (self.source_agent, self.target_agent)
        else:
            kind, value, known = "task", task, (self.training_task, self.target_task)
        raise PvedError(
            f"unknown {kind} {value!r} for {self.name}; its {kind}s: {', '.join(known)}"
        )

    def robot_state_of(self, agent: str) -> tuple[int, ...] | None:
        """The observation indices of ``agent``'s robot state the spec names (None: its
        envs report their own)."""
        return dict(self.robot_state).get(agent)

    def policy_config(self, agent: str, task: str) -> PPOConfig:
        """The PPO config used to train ``agent`` on ``task`` for this pair."""
        for over_agent, over_task, cfg in self.policy_overrides:
            if (over_agent, over_task) == (agent, task):
                return cfg
        return self.policy


#: What a protocol's tuning may score its candidates by (``ProtocolBudget.select_by``).
SELECT_BY = ("final", "auc")


@dataclass(frozen=True)
class ProtocolBudget:
    """How much of the paper's protocol (IV.A) one ``pved protocol`` run does.

    ``None`` fields take the pair preset's value; steps per transfer run are the preset's
    ``protocol_steps[name]``.

    Attributes:
        name: ``smoke`` (minutes on a laptop: checks that every stage connects),
            ``quick`` (a first real answer) or ``paper`` (the full protocol).
        tuning_seeds, evaluation_seeds: PPO seeds of the transfer runs (paper IV.A).
        source_policies: source target-task policies (seeds 0..k-1); each evaluation
            seed is run once per source policy.
        model_inits: model initialisations (seeds 0..k-1) tried at the selected beta.
        beta_grid_size: how many of the grid's values to try (None: all).
        beta_grid_extensions: how many decades the search may go past either end of the
            grid: while the best beta so far is the largest (smallest) one tried, the next
            decade up (down) is tried, so that the chosen beta lies inside what was
            searched, or at this limit.
        eval_every, eval_episodes, final_eval_episodes: learning-curve schedule.
        pair_episodes, model_epochs, bank_episodes, policy_steps: sizes of the earlier
            stages; ``policy_steps`` only matters for policies the package does not ship.
        steps_of: the budget whose steps per transfer run this one takes (None: its
            own name's, ``PairPreset.protocol_steps``).
        select_by: what a tuning candidate (β, then init) is scored by on the tuning
            seeds: ``"final"``, the pair's metric after training (paper IV.A), or
            ``"auc"``, the normalised area under its learning curve of that metric
            (``pved.analysis.run_curves.auc``; issue 64's goal is the area). The final
            return breaks ties either way.
    """

    name: str
    tuning_seeds: tuple[int, ...] = TUNING_SEEDS
    evaluation_seeds: tuple[int, ...] = EVALUATION_SEEDS
    source_policies: int = 3
    model_inits: int = 3
    beta_grid_size: int | None = None
    beta_grid_extensions: int = 2
    eval_every: int | None = None
    eval_episodes: int | None = None
    final_eval_episodes: int | None = None
    pair_episodes: int | None = None
    model_epochs: int | None = None
    bank_episodes: int | None = None
    policy_steps: int | None = None
    steps_of: str | None = None
    select_by: str = "final"

    def __post_init__(self) -> None:
        if self.select_by not in SELECT_BY:
            raise PvedError(
                f"select_by must be one of {', '.join(SELECT_BY)}, got {self.select_by!r}"
            )

    @property
    def steps_budget(self) -> str:
        """The budget name to look up the steps per transfer run under."""
        return self.steps_of or self.name


BUDGETS: dict[str, ProtocolBudget] = {
    # every stage of the protocol on a few thousand steps: a CI test, not a result
    "smoke": ProtocolBudget(
        name="smoke",
        tuning_seeds=TUNING_SEEDS[:2],
        evaluation_seeds=EVALUATION_SEEDS[:2],
        source_policies=1,
        model_inits=2,
        beta_grid_size=2,
        beta_grid_extensions=0,
        eval_every=4096,
        eval_episodes=16,
        final_eval_episodes=32,
        pair_episodes=64,
        model_epochs=2,
        bank_episodes=16,
        policy_steps=16_384,
    ),
    # the full design with three tuning seeds and shorter runs
    "quick": ProtocolBudget(name="quick", tuning_seeds=TUNING_SEEDS[:3]),
    # quick's design and steps, evaluated on seeds the paper's budget never uses: where a
    # method beyond the paper is chosen before its paper-budget runs (pre-registration,
    # docs/decisions/protocol.md); quick's tuning runs are the same runs, so they copy
    "screen": ProtocolBudget(
        name="screen",
        tuning_seeds=TUNING_SEEDS[:3],
        evaluation_seeds=SCREEN_SEEDS,
        steps_of="quick",
    ),
    # screen's runs, β and init chosen by the area under the tuning runs' learning curves
    # instead of their final score (docs/decisions/protocol.md, "The rule's amendment")
    "screen-auc": ProtocolBudget(
        name="screen-auc",
        tuning_seeds=TUNING_SEEDS[:3],
        evaluation_seeds=SCREEN_SEEDS,
        steps_of="quick",
        select_by="auc",
    ),
    # paper IV.A: 5 tuning seeds, 3 source policies x 5 evaluation seeds, 3 model inits
    "paper": ProtocolBudget(name="paper"),
    # the paper's protocol with 81 evaluation runs a method instead of 15: enough to tell
    # apart two success rates 0.2 apart when every run ends all or nothing
    # (docs/decisions.md, "The paper-wide budget"); its first 15 are the paper's runs
    "paper-wide": ProtocolBudget(
        name="paper-wide", evaluation_seeds=WIDE_EVALUATION_SEEDS, steps_of="paper"
    ),
    # issue 64's count where runs end near 0 or 1 (reacher, jaco-fetch): 3 sources x 15
    # seeds = 45 runs a method, paper-wide's first 15 seeds, so its runs copy both ways
    "paper-45": ProtocolBudget(
        name="paper-45", evaluation_seeds=WIDE_EVALUATION_SEEDS[:15], steps_of="paper"
    ),
}


def get_budget(name: str) -> ProtocolBudget:
    """The protocol budget ``name``; an unknown name raises :class:`PvedError`."""
    try:
        return BUDGETS[name]
    except KeyError:
        raise PvedError(f"unknown budget {name!r}; known budgets: {', '.join(BUDGETS)}") from None


EVAL_NUM_ENVS = 16  # env copies an evaluation runs on, at most (one batched pass)
