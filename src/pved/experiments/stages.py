"""The pipeline's stages as Python functions; every CLI verb is a thin layer over one.

Each stage reads files, writes its run directory (``pved.runs``) and returns the path
of what it produced (or its result), so stages can be rerun, resumed, skipped when
done, or replaced by the user's own data. Each takes the pair resolved at the door
(:func:`pved.pair.resolve_pair`), or its name or spec file, which it resolves once:

    train_policy  -> runs/<pair>/policy/<Agent>-<Task>/seed<k>/policy.pt
    collect_pairs -> runs/<pair>/pairs/<align>/seed<k>/pairs.npz
    train_model   -> runs/<pair>/model/<model>/seed<k>/model.pt
    build_bank    -> runs/<pair>/bank/<Agent>-<Task>/seed<k>/bank.npz
    transfer      -> runs/<pair>/transfer/<method>/seed<k>/{policy.pt,result.json}

One module past 600 lines on purpose: it holds the five stages and nothing else, each a
short function over its run directory that every CLI verb and the protocol look up here;
their helpers already live beside it (transfer_spec, sources, pved.run_layout).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved import __version__
from pved.checks import check_int, check_seed, check_writable, given, named_options
from pved.config import EVAL_NUM_ENVS, PairPreset
from pved.envs import BatchedEnv, make_batched
from pved.envs.registry import get_entry
from pved.errors import OptionError, PvedError
from pved.experiments.sources import check_one_source, open_recorded, recorded_episodes
from pved.experiments.transfer_spec import TransferSpec, set_guide_gate, transfer_spec
from pved.models import build_model  # noqa: F401  (re-exported for notebooks)
from pved.models.registry import load_model, save_model
from pved.models.train import COLLAPSE_NATS, shared_subspace_collapsed
from pved.models.train import train_model as fit_model
from pved.pair import Pair, resolve_pair
from pved.pairing.align import align as align_steps
from pved.pairing.collect import (
    collect_episode_pairs,
    env_header,
    pair_recorded_episodes,
    pairs_to_dataset,
)
from pved.pairing.dataset import load_dataset, save_dataset
from pved.pairing.rounds import (
    Embedder,
    SharedFit,
    base_alignment,
    dtw_rounds,
    phase_alignment,
)
from pved.rl.evaluate import evaluate_policy
from pved.rl.external import load_policy_file
from pved.rl.policy import Policy
from pved.rl.ppo import CHECKPOINT_SECONDS, check_checkpoint_seconds, train_ppo
from pved.run_layout import (
    bank_rollout_steps,
    check_bank_for,
    check_dataset_for,
    check_model_for,
    model_dataset_path,
    policy_path,
)
from pved.runs import Run, atomic_write_bytes, atomic_write_json, file_digest, run_file
from pved.spec import preset_for_agent
from pved.transfer.align_guide import AlignGuide, matched_distance_limit
from pved.transfer.methods import get_method
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import (
    bank_dt,
    bank_from_episodes,
    bank_time_scale,
    build_source_bank,
    load_bank,
    save_bank,
)


def _eval_env(env_name: str, episodes: int, **kwargs: Any) -> BatchedEnv:
    """The batched env evaluations run on: at most ``EVAL_NUM_ENVS`` copies, and no more
    copies than episodes (a copy without an episode to run would still be stepped)."""
    return make_batched(env_name, max(1, min(EVAL_NUM_ENVS, episodes)), **kwargs)


def _eval_fn(
    env_name: str,
    episodes: int,
    seed: int,
    env_kwargs: dict[str, Any] | None = None,
    info_keys: tuple[str, ...] = (),
) -> Callable[[Policy, int], dict[str, float]]:
    """Evaluation on a fresh, unshaped copy of the env, with seeds apart from training's;
    ``info_keys`` are averaged at episode end (e.g. ``x_position``: distance travelled)."""
    env = _eval_env(env_name, episodes, **(env_kwargs or {}))

    def evaluate(policy: Policy, env_steps: int) -> dict[str, float]:
        del env_steps
        stats = evaluate_policy(policy, env, episodes=episodes, seed=seed, info_keys=info_keys)
        return {f"eval/{k}": v for k, v in stats.items()}

    return evaluate


def train_policy(
    agent: str,
    task: str,
    *,
    seed: int = 0,
    steps: int | None = None,
    reward: str | None = None,
    runs_root: Path | None = None,
    eval_episodes: int | None = None,
    progress: bool = True,
    checkpoint_every_s: float | None = CHECKPOINT_SECONDS,
    pair: str | Path | Pair | None = None,
) -> Path:
    """PPO for any agent on any task (``pved train-policy``). Returns the policy file.

    ``pair`` (a name or a spec file) is the pair whose env and PPO config the agent's
    task takes (default: the first pair the agent is in).

    Evaluated every ``eval_every`` steps of the pair's PPO config on ``eval_episodes``
    (default: the preset's ``policy_eval_episodes``). With the preset's
    ``policy_keep_best``, the policy of the evaluation point with the best mean return
    (the end of training included) is the one saved, and ``result.json`` says which step
    it came from; judge it on fresh episodes (``pved evaluate``), not on these.
    ``checkpoint_every_s``: wall-clock seconds between checkpoints (:func:`train_ppo`)."""
    pair = resolve_pair(preset_for_agent(agent) if pair is None else pair, runs_root)
    preset = pair.preset
    if agent not in (preset.source_agent, preset.target_agent):
        raise PvedError(
            f"unknown agent {agent!r} for {preset.name}: its agents are {preset.source_agent} "
            f"and {preset.target_agent}"
        )
    name, spec_kwargs = pair.env(agent, task)
    with named_options(seed="--seed", total_steps="--steps"):
        ppo = dataclasses.replace(
            preset.policy_config(agent, task), seed=seed, **given(total_steps=steps)
        )
    episodes = (
        preset.policy_eval_episodes
        if eval_episodes is None
        else check_int("--eval-episodes", eval_episodes, low=1)
    )
    check_checkpoint_seconds(checkpoint_every_s, "--checkpoint-seconds")
    if reward is not None and not isinstance(reward, str):
        raise OptionError("--reward", reward, "the name of a reward variant")
    state = spec_kwargs.pop("robot_state", None)
    # the spec's env arguments (none for a built-in pair's: their hashes stand)
    env_kwargs = {**spec_kwargs, **({"reward": reward} if reward else {})}
    config = {"stage": "policy", "env_id": name, "env_kwargs": env_kwargs, "ppo": ppo}
    run = Run(pair.runs.run("policy", f"{agent}-{task}", seed), config)
    policy_file = run.path / "policy.pt"
    if run.is_done() and policy_file.exists():
        return policy_file
    check_writable("--runs", run.path)
    # the envs check the reward variant: made before the run directory is
    env = make_batched(name, ppo.num_envs, robot_state=state, **env_kwargs)
    eval_fn = _eval_fn(name, episodes, seed + 10**6, env_kwargs, preset.eval_info_keys)
    run.start()
    metadata = {
        "env_id": name,
        "env_kwargs": env_kwargs,
        "seed": seed,
        "steps": ppo.total_steps,
        "pved_version": __version__,
    }
    best_file, best_stats = run.path / "best_policy.pt", run.path / "best_policy.json"

    def evaluate_and_keep_best(policy: Policy, env_steps: int) -> dict[str, float]:
        stats = eval_fn(policy, env_steps)
        if preset.policy_keep_best and env_steps > 0:
            # on disk, so that a resumed run still knows the best point before it
            best = json.loads(best_stats.read_text()) if best_stats.exists() else None
            if best is None or stats["eval/return_mean"] > best["eval/return_mean"]:
                policy.save(best_file, {**metadata, "selected_step": env_steps})
                atomic_write_json(best_stats, {"step": env_steps, **stats})
        return stats

    def no_longer_falls_nor_improves() -> bool:
        """The preset's early stop: the last ``policy_stop_evaluations`` evaluations (read
        back from the run, so that a resumed run counts those before it) all completed
        at least ``policy_stop_completion`` of their episodes, and the last one's mean
        return exceeds the one before by less than ``policy_stop_gain`` of it."""
        bar, count = preset.policy_stop_completion, preset.policy_stop_evaluations
        evals = [r for r in run.read_metrics() if "eval/completion_rate" in r]
        if bar is None or len(evals) < max(count, 2):
            return False
        before, now = evals[-2]["eval/return_mean"], evals[-1]["eval/return_mean"]
        steady = all(r["eval/completion_rate"] >= bar for r in evals[-count:])
        return steady and now - before < preset.policy_stop_gain * abs(before)

    policy = train_ppo(
        env,
        ppo,
        run,
        eval_fn=evaluate_and_keep_best,
        stop_fn=no_longer_falls_nor_improves,
        progress=progress,
        checkpoint_every_s=checkpoint_every_s,
    )
    if preset.policy_keep_best and best_stats.exists():
        best = json.loads(best_stats.read_text())
        atomic_write_bytes(policy_file, best_file.read_bytes())
        final = {k: v for k, v in best.items() if k.startswith("eval/")}
        final["selected_step"] = best["step"]
    else:
        final = {k: v for k, v in run.read_metrics()[-1].items() if k.startswith("eval/")}
        policy.save(policy_file, metadata)
    trained = int(policy.metadata.get("training_steps", ppo.total_steps))
    run.finish(
        {
            "policy": str(policy_file),
            "env_id": name,
            "steps": ppo.total_steps,
            "trained_steps": trained,
            **final,
        }
    )
    return policy_file


def collect_pairs(
    pair: str | Path | Pair,
    *,
    source_policy: Path | str | None = None,
    target_policy: Path | str | None = None,
    episodes: int | None = None,
    seed: int = 0,
    align: str | None = None,
    task: str | None = None,
    runs_root: Path | None = None,
    progress: bool = True,
    source_dataset: Path | str | None = None,
) -> Path:
    """Paired rollouts of both agents' policies on ``task`` (``pved collect-pairs``).

    With ``source_dataset`` (a Minari dataset id or folder, ``pved.pairing.minari_io``) the
    source's side is its recorded episodes (default all; ``episodes`` the first ones) and
    the target is reset to each one's task parameters (``experiments.sources``).

    ``task`` is the pair's training task (default; paper IV.A) or its target task. The
    latter is not the paper's setting (the target agent has no policy for its target
    task before transfer); it is an analysis option: a model trained on such pairs has
    seen the target task's states, so transfer with it says what the training task's
    coverage costs. Both agents of a target-task pair share the parameters a bank is
    matched on (``bank_match_keys``: the hole, the button), as the training task's share
    ``shared_task_keys``. A pair whose envs report no shared parameter (``[tasks]
    shared = []``, e.g. two stock Gymnasium envs) pairs the episodes by seed alone:
    the k-th episodes of both agents start from resets with the same seed.

    ``pair`` is a pair's name, a spec file or a resolved pair (:func:`pved.pair.resolve_pair`)."""
    pair = resolve_pair(pair, runs_root)
    preset, cfg = pair.preset, pair.preset.pairing
    # the options checked as the pairing config checks its own fields; the run's config
    # keeps the preset's pairing config (its hash is that of the runs made before)
    with named_options(episodes="--episodes", align="--align", seed="--seed"):
        dataclasses.replace(cfg, **given(episodes=episodes, align=align, seed=seed))
    check_one_source(source_policy, source_dataset)
    recorded = None if source_dataset is None else open_recorded(source_dataset)
    if recorded is not None and episodes is None:
        episodes = recorded.episodes
    episodes = cfg.episodes if episodes is None else episodes
    align = cfg.align if align is None else align
    task = preset.training_task if task is None else task
    if task not in (preset.training_task, preset.target_task):
        raise PvedError(
            f"unknown task {task!r} for {pair.name}: its tasks are {preset.training_task} "
            f"(training) and {preset.target_task} (target)"
        )
    on_training_task = task == preset.training_task
    shared_task_keys = preset.shared_task_keys if on_training_task else preset.bank_match_keys
    src_path = None if recorded else policy_path(pair, preset.source_agent, task, source_policy)
    tgt_path = policy_path(pair, preset.target_agent, task, target_policy)
    src_id, src_kwargs = pair.env(preset.source_agent, task)
    tgt_id, tgt_kwargs = pair.env(preset.target_agent, task)
    config = {
        "stage": "pairs",
        "pair": pair.name,
        "episodes": episodes,
        "seed": seed,
        "align": align,
        "pairing": cfg,
        "target_policy": file_digest(tgt_path),
        **pair.identity,
    }
    if recorded is None:
        assert src_path is not None
        config["source_policy"] = file_digest(src_path)
    else:
        config["source_dataset"] = recorded.provenance["digest"]
    run_name = align
    if not on_training_task:
        # only then, so the datasets made before the option keep their hashes and places
        config["task"] = task
        run_name = f"{task}-{align}"
    run = Run(pair.runs.run("pairs", run_name, seed), config, tensorboard=False)
    out = run.path / "pairs.npz"
    if run.is_done() and out.exists():
        return out
    check_writable("--runs", run.path)
    src_env = make_batched(src_id, cfg.num_envs, **src_kwargs)
    tgt_env = make_batched(tgt_id, cfg.num_envs, **tgt_kwargs)
    tgt_pol = load_policy_file(tgt_path, env=tgt_env, env_name=tgt_id)
    if recorded is None:
        assert src_path is not None
        src_pol = load_policy_file(src_path, env=src_env, env_name=src_id)
        run.start()
        pairs = collect_episode_pairs(
            src_env,
            tgt_env,
            src_pol,
            tgt_pol,
            episodes,
            shared_task_keys=shared_task_keys,
            deterministic=cfg.deterministic,
            seed=seed,
            progress=progress,
        )
    else:
        src_eps = recorded_episodes(recorded, src_id, src_env, shared_task_keys, episodes)
        run.start()
        pairs = pair_recorded_episodes(
            src_eps,
            tgt_env,
            tgt_pol,
            shared_task_keys=shared_task_keys,
            deterministic=cfg.deterministic,
            seed=seed,
            progress=progress,
        )
    header = {
        "pair": pair.name,
        "source_agent": preset.source_agent,
        "target_agent": preset.target_agent,
        "source_env_id": src_id,
        "target_env_id": tgt_id,
        **pair.identity,
        **(
            {"source_policy": str(src_path)}
            if recorded is None
            else {"source_dataset": recorded.provenance}
        ),
        "target_policy": str(tgt_path),
        **env_header(src_env, tgt_env),
        "alignment": align,
        "deterministic_actions": cfg.deterministic,
        "seed": seed,
    }
    # control periods, for alignment by physical time (None for envs without one)
    dt_s, dt_t = getattr(src_env, "dt", None), getattr(tgt_env, "dt", None)
    header.update(dt_source=dt_s, dt_target=dt_t)
    time_only = base_alignment(align, dt_s, dt_t)
    alignment = [
        align_steps(time_only, len(e_s.obs), len(e_t.obs), dt_s, dt_t) for e_s, e_t in pairs
    ]
    if align == "dtw":
        fit = _dtw_fit(preset, header, seed, progress)
        alignment, header["dtw"] = dtw_rounds(pairs, alignment, header, cfg.dtw_rounds, fit)
    if align == "phase":
        alignment, header["phase"] = phase_alignment(pairs, alignment, header)
        header["phase"]["base"] = time_only
    dataset = pairs_to_dataset(pairs, alignment, shared_task_keys=shared_task_keys, header=header)
    save_dataset(out, dataset)
    run.finish(
        {
            "dataset": str(out),
            "rows": len(dataset),
            **{
                k: dataset.header[k]
                for k in (
                    "success_rate_source",
                    "success_rate_target",
                    "mean_length_source",
                    "mean_length_target",
                )
            },
        }
    )
    return out


def _dtw_fit(preset: PairPreset, header: dict[str, Any], seed: int, progress: bool) -> SharedFit:
    """What a DTW round trains (:func:`pved.pairing.rounds.dtw_rounds`): the pair's
    ``dtw_model`` for ``dtw_epochs`` on the aligned rows, returned as its embedder of
    both agents' rows into their shared means."""
    cfg = preset.pairing
    config = preset.model_config(cfg.dtw_model, seed=seed, epochs=cfg.dtw_epochs)
    state_dims = (
        len(header["robot_state_indices_source"]),
        len(header["robot_state_indices_target"]),
    )

    def fit(x_s: np.ndarray, x_t: np.ndarray) -> Embedder:
        model = fit_model(cfg.dtw_model, x_s, x_t, config, state_dims=state_dims, progress=progress)

        def embed(rows_s: np.ndarray, rows_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            with torch.no_grad():
                emb_s = model.shared_source(torch.as_tensor(rows_s)).mean.numpy()
                emb_t = model.shared_target(torch.as_tensor(rows_t)).mean.numpy()
            return emb_s, emb_t

        return embed

    return fit


def train_model(
    pair: str | Path | Pair,
    model: str = "pved",
    *,
    dataset: Path | str | None = None,
    seed: int = 0,
    epochs: int | None = None,
    runs_root: Path | None = None,
    progress: bool = True,
) -> Path:
    """Fit a shared-space model on a paired dataset (``pved train-model``). A dataset
    collected for another pair, agents or spec is refused before the fit."""
    pair = resolve_pair(pair, runs_root)
    preset = pair.preset
    with named_options(epochs="--epochs", seed="--seed"):
        model_cfg = preset.model_config(model, seed=seed, epochs=epochs)
    data_path = (
        run_file(dataset, "pairs.npz", "dataset")
        if dataset is not None
        else pair.runs.dataset(preset.pairing.align)
    )
    data = load_dataset(data_path)
    data.check_agents(preset.source_agent, preset.target_agent)
    check_dataset_for(pair, data.header, data_path)
    # the envs the pairs were collected on: the training task's unless `--task` chose another
    task = preset.training_task
    for env_task in (preset.training_task, preset.target_task):
        if (
            data.header.get("target_env_id")
            == preset.agent_env(preset.target_agent, env_task).env_id
        ):
            task = env_task
    src_id, src_kwargs = pair.env(preset.source_agent, task)
    tgt_id, tgt_kwargs = pair.env(preset.target_agent, task)
    src_id = data.header.get("source_env_id", src_id)
    tgt_id = data.header.get("target_env_id", tgt_id)
    src_env = make_batched(src_id, 1, **src_kwargs)
    tgt_env = make_batched(tgt_id, 1, **tgt_kwargs)
    data.check_dims(
        src_env.single_observation_space.shape[0],
        src_env.single_action_space.shape[0],
        tgt_env.single_observation_space.shape[0],
        tgt_env.single_action_space.shape[0],
    )
    config = {
        "stage": "model",
        "pair": pair.name,
        "model": model,
        "dataset": file_digest(data_path),
        "model_config": model_cfg,
        **pair.identity,
    }
    run = Run(pair.runs.run("model", model, seed), config)
    out = run.path / "model.pt"
    if run.is_done() and out.exists():
        return out
    check_writable("--runs", run.path)
    run.start()
    x_s, x_t = data.model_inputs()
    fitted = fit_model(
        model, x_s, x_t, model_cfg, run, state_dims=data.state_dims, progress=progress
    )
    save_model(
        fitted,
        out,
        {
            "pair": pair.name,
            "model": model,
            # its digest, not its path: a model names no place on the machine it was made on
            "dataset": file_digest(data_path),
            "source_agent": preset.source_agent,
            "target_agent": preset.target_agent,
            "seed": seed,
            "robot_state_indices_source": data.header["robot_state_indices_source"],
            "robot_state_indices_target": data.header["robot_state_indices_target"],
            **pair.identity,
        },
    )
    last = run.read_metrics()[-1] if run.read_metrics() else {}
    val = {k.removeprefix("val/"): v for k, v in last.items() if k.startswith("val/")}
    collapsed = shared_subspace_collapsed(val)
    if collapsed:
        warnings.warn(
            f"{model} on {pair.name}: both shared posteriors sit on the prior (validation KL of c "
            f"below {COLLAPSE_NATS} nats), so its shaping reward is zero; see "
            "docs/decisions.md, 'Consistency warm-up'",
            stacklevel=2,
        )
    run.finish(
        {
            "model": str(out),
            **{k: v for k, v in last.items() if k != "step"},
            "shared_collapsed": collapsed,
            "train_backend": fitted.metadata.get("train_backend"),
        }
    )
    return out


def build_bank(
    pair: str | Path | Pair,
    *,
    source_policy: Path | str | None = None,
    episodes: int | None = None,
    seed: int = 0,
    runs_root: Path | None = None,
    source_dataset: Path | str | None = None,
) -> Path:
    """Rollouts of the source's target-task policy, matched into Eq. 10 at transfer; with
    ``source_dataset`` (a Minari dataset id or folder) its recorded episodes instead
    (default all; ``episodes`` the first ones)."""
    pair = resolve_pair(pair, runs_root)
    preset = pair.preset
    if episodes is not None:
        with named_options(bank_episodes="--episodes"):
            dataclasses.replace(preset.transfer, bank_episodes=episodes)
    check_seed("--seed", seed)
    check_one_source(source_policy, source_dataset)
    recorded = None if source_dataset is None else open_recorded(source_dataset)
    if recorded is not None and episodes is None:
        episodes = recorded.episodes
    episodes = preset.transfer.bank_episodes if episodes is None else episodes
    name, env_kwargs = pair.bank_env
    config: dict[str, Any] = {
        "stage": "bank",
        "env_id": name,
        "episodes": episodes,
        "seed": seed,
        "match_keys": preset.bank_match_keys,
        **pair.identity,
    }
    # rollouts as long as the target's episode on the pairs' time base; only where that
    # is past the source env's own limit (humanoid-ant), so other banks keep their configs
    step_limit = bank_rollout_steps(pair) if source_dataset is None else None
    if step_limit is not None:
        config["step_limit"] = step_limit
    if recorded is None:
        path = policy_path(pair, preset.source_agent, preset.target_task, source_policy)
        config["source_policy"] = file_digest(path)
    else:
        config["source_dataset"] = recorded.provenance["digest"]
    out = pair.runs.bank(preset.source_agent, preset.target_task, seed)
    run = Run(out.parent, config, tensorboard=False)
    if run.is_done() and out.exists():
        return out
    check_writable("--runs", run.path)
    env = _eval_env(name, episodes, step_limit=step_limit, **env_kwargs)
    # a spec's digest only for a pair of its own: a built-in pair's bank is the bytes it
    # always was, so the transfer runs that hash it keep their configs
    identity = pair.identity
    if recorded is None:
        policy = load_policy_file(path, env=env, env_name=name)
        run.start()
        bank = build_source_bank(
            env,
            policy,
            episodes,
            preset.bank_match_keys,
            seed=seed,
            header={"env_id": name, "source_policy": str(path), **identity},
        )
    else:
        eps = recorded_episodes(recorded, name, env, preset.bank_match_keys, episodes)
        run.start()
        bank = bank_from_episodes(
            eps,
            preset.bank_match_keys,
            env.robot_state_indices,
            header={"env_id": name, "source_dataset": recorded.provenance, **identity},
            dt=getattr(env, "dt", None),
        )
    save_bank(out, bank)
    run.finish(
        {"bank": str(out), "episodes": episodes, "success_rate": bank.header["success_rate"]}
    )
    return out


def transfer(
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
    progress: bool = True,
    shaping_start: int = 0,
    shaping_form: str | None = None,
    shaping_action: str = "mean",
    checkpoint_every_s: float | None = CHECKPOINT_SECONDS,
) -> dict[str, Any]:
    """PPO of the target agent on the target task (``pved transfer``); returns
    ``result.json``.

    ``pair`` is a :class:`~pved.pair.Pair` resolved at the door, or its name or spec file
    (resolved here, once; ``runs_root`` moves its runs). The run lives in
    ``<runs>/<pair>/transfer/<run_name or method>/seed<seed>``; a ``run_name`` keeps apart
    runs of one method with different betas, models or banks.

    ``method`` is a name of :data:`pved.transfer.methods.METHODS`: a model's name
    (``pved``, a variant, ``gupta2017``: the target agent's restricted reward plus the
    Eq. 10 shaping term of that model), a method beyond the paper (``pved-potential``),
    ``ppo`` (the restricted reward alone) or ``oracle`` (the source's full reward, no
    shaping: what the target could do if the reward told it everything). Evaluation
    always uses the target task's default env, so every method is measured alike.
    ``shaping_start`` (env steps; not in the paper) holds the shaping term at 0 until
    then; ``shaping_form`` (default: the method's) replaces the form Eq. 10's distance
    enters the reward in, e.g. ``"log1p"`` for −β·log(1 + D) (:class:`LatentShaping`).
    ``shaping_action``: the target action Eq. 10 encodes, ``"mean"`` (the policy's mean
    action, as in the pairs and the bank) or ``"taken"`` (the sampled exploration action).
    ``checkpoint_every_s``: wall-clock seconds between checkpoints (:func:`train_ppo`; not
    part of the run's config).

    Everything is checked before the run directory is made: the options, where the run
    goes, and that the model and bank were made for this pair (:func:`check_model_for`,
    :func:`check_bank_for`)."""
    torch.set_num_threads(1)
    check_checkpoint_seconds(checkpoint_every_s, "--checkpoint-seconds")
    # the pair is resolved once, here (a name or a spec file) or by the caller: the spec
    # carries it, and nothing below looks it up again
    spec = transfer_spec(
        pair,
        method,
        seed=seed,
        model_path=model_path,
        bank_path=bank_path,
        steps=steps,
        beta=beta,
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        final_eval_episodes=final_eval_episodes,
        runs_root=runs_root,
        run_name=run_name,
        shaping_start=shaping_start,
        shaping_form=shaping_form,
        shaping_action=shaping_action,
    )
    run = Run(spec.run_dir, spec.config)
    if run.is_done():
        return run.read_result()
    check_writable("--runs", run.path)
    env = _training_env(spec, method)
    guide = getattr(env, "action_guide", None)
    name, env_kwargs = spec.pair.target_env
    info_keys = spec.pair.preset.eval_info_keys
    eval_fn = _eval_fn(name, spec.eval_episodes, 10**6 + seed, env_kwargs, info_keys=info_keys)
    policy = train_ppo(  # starts the run (Run.start) before its first step
        env,
        spec.ppo,
        run,
        eval_fn=eval_fn,
        progress=progress,
        checkpoint_every_s=checkpoint_every_s,
    )
    policy_file = run.path / "policy.pt"
    policy.save(
        policy_file,
        {
            "env_id": name,
            "seed": seed,
            "method": method,
            "steps": spec.ppo.total_steps,
            "pved_version": __version__,
        },
    )
    final_episodes = spec.final_episodes
    final = evaluate_policy(
        policy,
        _eval_env(name, final_episodes, **env_kwargs),
        episodes=final_episodes,
        seed=2 * 10**6 + seed,
        info_keys=info_keys,
    )
    return run.finish(
        {
            "method": method,
            "seed": seed,
            "steps": spec.ppo.total_steps,
            "policy": str(policy_file),
            # pved-align's loss in numpy or by autograd: rounding apart, the same run
            **({"guide_backend": guide.backend} if isinstance(guide, AlignGuide) else {}),
            **({"guide_d_limit": guide.d_limit} if isinstance(guide, AlignGuide) else {}),
            **{f"final/{k}": v for k, v in final.items()},
        }
    )


def _training_env(spec: TransferSpec, method: str) -> BatchedEnv:
    """The env a transfer run trains on: the target's, wrapped in Eq. 10's shaping (or a
    guide) for a shaped method, whose model and bank are checked against the pair first
    (:func:`check_model_for`, :func:`check_bank_for`)."""
    pair = spec.pair
    env = make_batched(spec.env_id, spec.ppo.num_envs, **spec.train_env_kwargs)
    if spec.shaping_inputs is None:
        return env
    model_path, bank_path = spec.shaping_inputs
    model, bank = load_model(model_path), load_bank(bank_path)
    check_model_for(pair, model, model_path, get_method(method).model, env.robot_state_indices)
    check_bank_for(pair, bank, bank_path, model)
    shaping = LatentShaping(
        model,
        bank,
        spec.beta,
        env.robot_state_indices,
        start=spec.shaping_start,
        stop=spec.shaping_stop,
        form=spec.shaping_form,
        time_scale=bank_time_scale(
            pair.preset.pairing.align, bank_dt(bank), getattr(env, "dt", None)
        ),
        action=spec.shaping_action,
        gamma=spec.ppo.gamma,
        align_anneal=spec.align_anneal,
    )
    shaped = ShapedBatchedEnv(env, shaping, pair.preset.bank_match_keys)
    if shaped.action_guide is not None:  # PPO's reward gate scores episodes by the task
        set_guide_gate(shaped.action_guide, spec.config["guide_limits"])
    if isinstance(shaped.action_guide, AlignGuide):  # its D gate reads the model's pairs
        pairs = load_dataset(model_dataset_path(pair, model))
        shaped.action_guide.d_limit = matched_distance_limit(model, *pairs.model_inputs())
    return shaped


def evaluate(
    policy_path: Path | str,
    env_name: str | None = None,
    *,
    episodes: int = 500,
    seed: int = 0,
    reward: str | None = None,
    pair: str | Path | Pair | None = None,
) -> dict[str, float]:
    """Evaluate a saved policy (``pved evaluate``): success rate, return, length, and the
    pair's metric (e.g. the distance travelled along x for the locomotion pairs).

    With ``pair`` (a name or a spec file), ``env_name`` is one of the pair's envs
    (default: the target agent's on the target task), made with the spec's arguments,
    and the metric is the pair's; without, any env id (a stock Gymnasium one reports
    success, return and length)."""
    check_int("--episodes", episodes, low=1)
    check_seed("--seed", seed)
    env_kwargs: dict[str, Any] = {}
    info_keys: tuple[str, ...] = ()
    if pair is not None:
        pair = resolve_pair(pair)
        preset = pair.preset
        agent, task = preset.target_agent, preset.target_task
        if env_name is not None:
            found = [e for e in preset.envs if e.env_id == env_name]
            if not found:
                ids = ", ".join(dict.fromkeys(e.env_id for e in preset.envs))
                raise PvedError(f"env {env_name!r} is not one of {preset.name}'s: {ids}")
            agent, task = found[0].agent, found[0].task
        env_name, env_kwargs = pair.env(agent, task)
        info_keys = preset.eval_info_keys
    elif env_name is None:
        raise PvedError("evaluate needs --env or --pair")
    elif env_name.startswith("pved/"):
        info_keys = preset_for_agent(get_entry(env_name).agent).eval_info_keys
    env = _eval_env(env_name, episodes, **env_kwargs, **({"reward": reward} if reward else {}))
    policy = load_policy_file(
        run_file(policy_path, "policy.pt", "policy"), env=env, env_name=env_name
    )
    return evaluate_policy(policy, env, episodes=episodes, seed=seed, info_keys=info_keys)


def preset_summary(preset: PairPreset) -> dict[str, Any]:
    """A small JSON-able description of a preset (for reports)."""
    return {
        "pair": preset.name,
        "source": preset.source_agent,
        "target": preset.target_agent,
        "training_task": preset.training_task,
        "target_task": preset.target_task,
        "alpha": [preset.model.alpha1, preset.model.alpha2, preset.model.alpha3],
        "beta": preset.transfer.beta,
    }


__all__ = [
    "build_bank",
    "collect_pairs",
    "evaluate",
    "np",
    "train_model",
    "train_policy",
    "transfer",
]
