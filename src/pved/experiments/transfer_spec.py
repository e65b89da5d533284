"""A transfer run resolved from its arguments before anything runs (``pved transfer``).

:func:`transfer_spec` says where the run lives, the config its hash is taken of (with
Eq. 10's entries, :func:`eq10_config`) and what it trains on, reading the model and
bank only to hash them; the transfer stage (:func:`pved.experiments.stages.transfer`)
runs it, and a protocol or an exported batch plans its jobs by it without running.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from pved.checks import check_int, given, named_options
from pved.config import PairPreset
from pved.errors import PvedError
from pved.models.registry import MODELS
from pved.pair import Pair, resolve_pair
from pved.rl.guide import GATE_EPISODES, GATE_Z, GUIDE_GRAD_RATIO
from pved.rl.ppo import PPOConfig
from pved.runs import file_digest, run_file
from pved.transfer.align_guide import (
    ALIGN_ANNEAL,
    D_GATE_FACTOR,
    D_GATE_QUANTILE,
    D_GATE_ROWS,
    AlignGuide,
)
from pved.transfer.methods import get_method
from pved.transfer.prior_guide import PriorGuide, check_prior_model
from pved.transfer.shaping import GUIDE_FORMS, check_shaping_action, check_shaping_form


@dataclasses.dataclass(frozen=True)
class TransferSpec:
    """A transfer run resolved from its arguments before anything runs: where it lives,
    the config its hash is taken of, and what it trains on.

    Attributes:
        pair: the pair, resolved (:func:`pved.pair.resolve_pair`).
        config: the resolved config (``config.json``; its hash decides whether a run
            directory holds this run).
        run_dir: ``runs_root/<pair>/transfer/<run_name or method>/seed<seed>``.
        env_id: the target agent's target-task env.
        ppo: PPO's config (seed, steps and curve interval applied).
        eval_episodes, final_episodes: episodes per curve point and of the final evaluation.
        train_env_kwargs: env options of the training env (the oracle's full reward).
        shaping_inputs: (model, source bank) of a shaped run; None for ``ppo``/``oracle``.
        beta: the shaping weight (Eq. 10).
        align_anneal: a guide form's anneal (``pved.transfer.shaping.GUIDE_FORMS``).
        shaping_stop: env steps by which a reward form's weight has fallen to 0 (the
            method's ``anneal`` of the run; 0: never, :class:`LatentShaping`).
    """

    pair: Pair
    config: dict[str, Any]
    run_dir: Path
    env_id: str
    ppo: PPOConfig
    eval_episodes: int
    final_episodes: int
    train_env_kwargs: dict[str, Any]
    shaping_inputs: tuple[Path, Path] | None
    beta: float
    shaping_start: int
    shaping_form: str
    shaping_action: str
    align_anneal: float = ALIGN_ANNEAL
    shaping_stop: int = 0


def eq10_config(bank_time: str, shaping_action: str = "mean") -> dict[str, Any]:
    """The entries of a shaped transfer run's config that say how Eq. 10 is computed
    (docs/decisions.md, "Transfer (Eq. 10)"): the bank read on the pairs' time base
    (``bank_time``: the pair's alignment, ``PairingConfig.align``), the
    target action encoded, and the term scaled by the shaped return's std but never
    clipped; and a target step past the end of its source episode compared with nothing
    (``source_end``; docs/decisions/transfer.md, "A target step past the source's end").
    Runs made before 2026-12-05 (``source_end``: before issue 64) computed otherwise and
    lack them, so their config hashes differ, and a protocol does not take them
    (``Job.required_config``)."""
    return {
        "bank_time": bank_time,
        "shaping_action": shaping_action,
        "reward_scaling": "term-scaled-unclipped",
        "source_end": "no-comparison",
    }


def gate_score(preset: PairPreset) -> str:
    """What the reward gate (``pved.rl.guide.RewardGate``) judges a finished training
    episode by: the pair's own measure of the task (``preset.metric``) for one episode,
    so that the gate closes once the task is being found and not once the body merely
    lasts longer (docs/decisions/transfer.md, "A guide that cannot take PPO's budget").
    ``success_rate``: its success; ``return_mean``, ``length_mean``, ``completion_rate``:
    its return, length, whether it ran to the time limit;
    ``<key>_mean`` of an ``info`` entry the pair evaluates by: that entry at its last step
    (``x_position`` for humanoid-ant). ``"never"`` where the target's reward does not
    measure the task (``preset.metric_in_target_reward``, False on walker-hopper): the
    gate would hand the run to a reward that cannot hold what the guide taught, so the
    guide acts for as long as its own weight says."""
    if not preset.metric_in_target_reward:
        return "never"
    metric = preset.metric
    named = {
        "success_rate": "is_success",
        "return_mean": "return",
        "length_mean": "length",
        "completion_rate": "completed",
    }
    if metric in named:
        return named[metric]
    key = metric.removesuffix("_mean")
    if metric.endswith("_mean") and key in preset.eval_info_keys:
        return key
    raise PvedError(
        f"{preset.name}: the reward gate cannot score an episode by the metric {metric!r} "
        "(success_rate, return_mean, length_mean, completion_rate or <info key>_mean of the "
        "metric's info_keys)"
    )


def guide_limits(form: str, preset: PairPreset) -> dict[str, Any]:
    """What bounds a guide form's loss on the mean action (``pved.rl.guide``): its
    gradient's norm at most ``grad_ratio`` times PPO's clipped one's, the reward gate's
    window, t, score (:func:`gate_score`) and least rise (the metric's resolution, the
    scale below which the pair's tuning calls a difference noise), and for the align form
    the D gate (``pved.transfer.align_guide``). In the run's config, so a run under other
    limits has another hash."""
    limits: dict[str, Any] = {
        "grad_ratio": GUIDE_GRAD_RATIO,
        "gate_episodes": GATE_EPISODES,
        "gate_z": GATE_Z,
        "gate_score": gate_score(preset),
        "gate_min_gap": float(preset.metric_resolution or 0.0),
    }
    if form == "align":
        limits["d_gate"] = {
            "quantile": D_GATE_QUANTILE,
            "factor": D_GATE_FACTOR,
            "rows": D_GATE_ROWS,
        }
    return limits


def set_guide_gate(guide: AlignGuide | PriorGuide, limits: dict[str, Any]) -> None:
    """Give a guide (``ShapedBatchedEnv.action_guide``) its reward gate's score and least
    rise from a run's ``guide_limits`` (:func:`guide_limits`): PPO builds the gate from
    them (``pved.rl.guide.RewardGate``)."""
    guide.gate_score = limits["gate_score"]
    guide.gate_min_gap = limits["gate_min_gap"]


def transfer_spec(
    pair: str | Path | Pair,
    method: str = "pved",
    *,
    seed: int = 20000,
    model_path: Path | str | None = None,
    bank_path: Path | str | None = None,
    steps: int | None = None,
    beta: float | None = None,
    eval_every: int | None = None,
    eval_episodes: int | None = None,
    final_eval_episodes: int | None = None,
    runs_root: Path | None = None,
    run_name: str | None = None,
    shaping_start: int = 0,
    shaping_form: str | None = None,
    shaping_action: str = "mean",
) -> TransferSpec:
    """The :class:`TransferSpec` of ``transfer(...)`` with the same arguments (see there).
    ``pair`` is resolved here (:func:`pved.pair.resolve_pair`; a :class:`Pair` is taken as
    it is, under ``runs_root`` when given), once for the whole run: the spec carries it.
    Reads the model and bank only to hash them; a missing one raises :class:`PvedError`."""
    recipe = get_method(method)  # an unknown method name fails here, before any file check
    shaping_form = recipe.shaping_form if shaping_form is None else shaping_form
    align_anneal = ALIGN_ANNEAL if recipe.anneal is None else recipe.anneal
    check_shaping_form(shaping_form)
    check_shaping_action(shaping_action)
    if shaping_form == "prior" and recipe.model is not None:  # before any file is read
        check_prior_model(MODELS[recipe.model])
    check_int("--shaping-start", shaping_start, low=0)
    pair = resolve_pair(pair, runs_root)
    preset = pair.preset
    # Every option lands in the transfer and PPO configs, which check their fields (a
    # negative or NaN beta, a negative count of final episodes): refused here, before a
    # file is read or a directory made, not after the training.
    with named_options(
        beta="--beta",
        eval_every="--eval-every",
        eval_episodes="--eval-episodes",
        final_eval_episodes="--final-eval-episodes",
        seed="--seed",
        total_steps="--steps",
    ):
        tcfg = dataclasses.replace(
            preset.transfer,
            **given(
                beta=beta,
                eval_every=eval_every,
                eval_episodes=eval_episodes,
                final_eval_episodes=final_eval_episodes,
            ),
        )
        # the learning curve's evaluation interval: the preset's unless given
        ppo = dataclasses.replace(
            tcfg.ppo,
            seed=seed,
            eval_every=tcfg.eval_every,
            **given(total_steps=steps),
        )
    beta, eval_episodes, final_episodes = tcfg.beta, tcfg.eval_episodes, tcfg.final_eval_episodes
    name, env_kwargs = pair.target_env
    config: dict[str, Any] = {
        "stage": "transfer",
        "pair": pair.name,
        "method": method,
        "env_id": name,
        "ppo": ppo,
        "eval_episodes": eval_episodes,
        "final_eval_episodes": final_episodes,
        **pair.identity,
    }
    shaping_inputs: tuple[Path, Path] | None = None
    shaping_stop = 0
    train_env_kwargs: dict[str, Any] = dict(env_kwargs)
    if recipe.train_reward == "full":
        if not name.startswith("pved/"):
            raise PvedError(
                f"the oracle trains on a pved env's full reward (reward='full'); {name} has "
                "no such variant"
            )
        train_env_kwargs["reward"] = "full"
        config["train_reward"] = "full"
    if recipe.model is not None:
        m_path = (
            run_file(model_path, "model.pt", "model")
            if model_path
            else pair.runs.model(recipe.model)
        )
        b_path = (
            run_file(bank_path, "bank.npz", "source bank")
            if bank_path
            else pair.runs.bank(preset.source_agent, preset.target_task)
        )
        for what, p in (("model", m_path), ("source bank", b_path)):
            if not p.exists():
                raise PvedError(f"{what} not found: {p} (run the earlier stages first)")
        shaping_inputs = (m_path, b_path)
        config.update(beta=beta, model=file_digest(m_path), bank=file_digest(b_path))
        config.update(eq10_config(preset.pairing.align, shaping_action))
        # both only when set, so the runs made before they existed keep their config hashes
        if shaping_start:
            config["shaping_start"] = shaping_start
        if shaping_form != "eq10":
            config["shaping_form"] = shaping_form
        if shaping_form in GUIDE_FORMS:
            config["align_anneal"] = align_anneal
            config["guide_limits"] = guide_limits(shaping_form, preset)
        elif recipe.anneal is not None:  # a reward form's term annealed (pved-anneal)
            if shaping_form == "potential":
                raise PvedError(
                    f"{method} anneals its term, which the potential form cannot take "
                    "(its Φ must stay one function): give another --shaping-form"
                )
            shaping_stop = max(1, round(recipe.anneal * ppo.total_steps))
            if shaping_stop <= shaping_start:
                raise PvedError(
                    f"--shaping-start {shaping_start}: {method}'s term is gone by step "
                    f"{shaping_stop} ({recipe.anneal:g} of the run); start it earlier"
                )
            config["reward_anneal"] = recipe.anneal
    if shaping_start and shaping_inputs is None:
        raise PvedError(f"a shaping start needs a shaping method; {method!r} has no shaping term")
    if shaping_form != "eq10" and shaping_inputs is None:
        raise PvedError(f"a shaping form needs a shaping method; {method!r} has no shaping term")
    return TransferSpec(
        pair=pair,
        config=config,
        run_dir=pair.runs.run("transfer", run_name or method, seed),
        env_id=name,
        ppo=ppo,
        eval_episodes=eval_episodes,
        final_episodes=final_episodes,
        train_env_kwargs=train_env_kwargs,
        shaping_inputs=shaping_inputs,
        beta=beta,
        shaping_start=shaping_start,
        shaping_form=shaping_form,
        shaping_action=shaping_action,
        align_anneal=align_anneal,
        shaping_stop=shaping_stop,
    )
