"""The pipeline's stages as Python functions; every CLI verb is a thin layer over one.

Each stage reads files, writes its run directory (``pved.runs``) and returns the path
of what it produced (or its result), so stages can be rerun, resumed, skipped when
done, or replaced by the user's own data:

    train_policy  -> runs/<pair>/policy/<Agent>-<Task>/seed<k>/policy.pt
    collect_pairs -> runs/<pair>/pairs/<align>/seed<k>/pairs.npz
    train_model   -> runs/<pair>/model/<model>/seed<k>/model.pt
    build_bank    -> runs/<pair>/bank/<Agent>-<Task>/seed<k>/bank.npz
    transfer      -> runs/<pair>/transfer/<method>/seed<k>/{policy.pt,result.json}
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved import __version__
from pved.checks import (
    check_int,
    check_number,
    check_seed,
    check_writable,
    given,
    named_options,
)
from pved.config import (
    EVAL_NUM_ENVS,
    PRETRAINED,
    TRAINED,
    PairPreset,
    get_preset,
    preset_for_agent,
)
from pved.envs import BatchedEnv, make_batched
from pved.envs.registry import get_entry
from pved.errors import OptionError, PvedError
from pved.models import build_model  # noqa: F401  (re-exported for notebooks)
from pved.models.base import SharedSpaceModel
from pved.models.registry import load_model, model_class, save_model
from pved.models.train import COLLAPSE_NATS, shared_subspace_collapsed
from pved.models.train import train_model as fit_model
from pved.pairing.align import (
    LEARNED_ALIGNMENTS,
    PHASE_WINDOW,
    dtw_indices,
    first_component,
    gait_phase,
    phase_indices,
)
from pved.pairing.align import align as align_steps
from pved.pairing.collect import (
    EpisodePair,
    collect_episode_pairs,
    env_header,
    pairs_to_dataset,
)
from pved.pairing.dataset import load_dataset, save_dataset
from pved.pretrained import pretrained_policy_path
from pved.rl.evaluate import evaluate_policy
from pved.rl.policy import Policy, load_policy
from pved.rl.ppo import CHECKPOINT_SECONDS, PPOConfig, check_checkpoint_seconds, train_ppo
from pved.runs import Run, atomic_write_bytes, atomic_write_json, run_path, safe_torch_load
from pved.spec import builtin_names, spec_identity
from pved.transfer.shaping import (
    LatentShaping,
    ShapedBatchedEnv,
    check_shaping_action,
    check_shaping_form,
)
from pved.transfer.source_bank import (
    SourceBank,
    bank_dt,
    bank_time_scale,
    build_source_bank,
    env_dt,
    load_bank,
    save_bank,
)

DEFAULT_RUNS = Path("runs")


def _eval_env(env_name: str, episodes: int, **kwargs: Any) -> BatchedEnv:
    """The batched env evaluations run on: at most ``EVAL_NUM_ENVS`` copies, and no more
    copies than episodes (a copy without an episode to run would still be stepped)."""
    return make_batched(env_name, max(1, min(EVAL_NUM_ENVS, episodes)), **kwargs)


NO_TRANSFER = "ppo"  # the target agent's restricted reward alone
ORACLE = "oracle"  # the target agent with the source's full reward, no shaping
REFERENCE_METHODS = (NO_TRANSFER, ORACLE)


def _hash_state(digest: Any, obj: Any) -> None:
    """Feed a loaded PyTorch state into ``digest`` by value: tensors by dtype, shape and
    bytes; dicts in key order; each part length-prefixed, so no two states collide by
    concatenation."""

    def part(tag: bytes, payload: bytes) -> None:
        digest.update(tag + len(payload).to_bytes(8, "little") + payload)

    if isinstance(obj, torch.Tensor):
        flat = obj.detach().cpu().contiguous().reshape(-1)
        part(b"T", f"{flat.dtype}{tuple(obj.shape)}".encode())
        part(b"B", flat.view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, dict):
        part(b"D", str(len(obj)).encode())
        for key in sorted(obj, key=repr):
            _hash_state(digest, key)
            _hash_state(digest, obj[key])
    elif isinstance(obj, (list, tuple)):
        part(b"L" if isinstance(obj, list) else b"U", str(len(obj)).encode())
        for item in obj:
            _hash_state(digest, item)
    else:  # str, int, float, bool, None: what a pved state holds besides tensors
        part(type(obj).__name__.encode(), repr(obj).encode())


def file_digest(path: Path) -> str:
    """Short content hash of an input file, so a changed input invalidates a done stage.

    A PyTorch file (policy, model) is hashed by the state it holds, not by its bytes:
    ``torch.save`` writes a fresh random serialization id and the temporary file's name
    into every file, and pickles equal strings differently by object identity, so two
    saves of one state differ byte for byte. A model retrained bit for bit then keeps
    the digest its transfer runs were made under."""
    data = Path(path).read_bytes()
    if data[:4] == b"PK\x03\x04":  # a zip archive: a PyTorch file, or a numpy .npz
        try:
            state = safe_torch_load(Path(path))
        except PvedError:  # not a PyTorch file: hashed by its bytes
            pass
        else:
            digest = hashlib.sha256(b"pved-torch-state")
            _hash_state(digest, state)
            return digest.hexdigest()[:16]
    return hashlib.sha256(data).hexdigest()[:16]


def env_of(preset: PairPreset, agent: str, task: str) -> tuple[str, dict[str, Any]]:
    """``agent``'s env on ``task`` in ``preset``: its id, and the arguments
    :func:`~pved.envs.make_batched` takes for it (the spec's ``kwargs``, and its
    ``robot_state`` where the spec names one)."""
    entry = preset.agent_env(agent, task)
    kwargs: dict[str, Any] = dict(entry.kwargs)
    state = preset.robot_state_of(agent)
    if state is not None:
        kwargs["robot_state"] = state
    return entry.env_id, kwargs


def policy_path(
    preset: PairPreset,
    agent: str,
    task: str,
    given: Path | str | None = None,
    runs_root: Path = DEFAULT_RUNS,
) -> Path:
    """The policy file ``agent`` acts with on ``task``: ``given`` (a file or its run
    directory), else what the pair's spec names: the policy shipped with pved, the
    pair's own ``pved train-policy`` run (seed 0, under ``runs_root``), or a file. Every
    stage finds its policies here, and reads them with :func:`load_agent_policy`."""
    if given is not None:
        return run_file(given, "policy.pt", f"{agent}'s policy")
    choice = preset.agent_env(agent, task).policy
    if choice == PRETRAINED:
        return pretrained_policy_path(agent, task)
    if choice == TRAINED:
        trained = run_path(runs_root, preset.name, "policy", f"{agent}-{task}", 0) / "policy.pt"
        if not trained.is_file():
            spec = preset.name if preset.name in builtin_names() else "SPEC.toml"
            raise PvedError(
                f"{agent}'s policy on {task} not found: {trained} (not trained yet: "
                f"pved train-policy --pair {spec} --agent {agent} --task {task})"
            )
        return trained
    return run_file(choice, "policy.pt", f"{agent}'s policy on {task} (the spec's)")


def load_agent_policy(path: Path) -> Policy:
    """The policy in file ``path`` (found by :func:`policy_path`): the one place a stage
    reads a source or target policy, so that another policy format is added here."""
    return load_policy(path)


def _check_policy(policy: Policy, env_name: str, env: BatchedEnv) -> None:
    """A policy made for another agent (its dims) is refused before it is rolled out."""
    obs_dim = env.single_observation_space.shape[0]
    act_dim = env.single_action_space.shape[0]
    if policy.obs_dim != obs_dim or policy.act_dim != act_dim:
        raise PvedError(
            f"policy dims (obs {policy.obs_dim}, act {policy.act_dim}) do not match {env_name} "
            f"(obs {obs_dim}, act {act_dim})"
        )


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
    runs_root: Path = DEFAULT_RUNS,
    eval_episodes: int | None = None,
    progress: bool = True,
    checkpoint_every_s: float | None = CHECKPOINT_SECONDS,
    pair: str | None = None,
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
    preset = preset_for_agent(agent) if pair is None else get_preset(pair)
    if agent not in (preset.source_agent, preset.target_agent):
        raise PvedError(
            f"unknown agent {agent!r} for {preset.name}: its agents are {preset.source_agent} "
            f"and {preset.target_agent}"
        )
    name, spec_kwargs = env_of(preset, agent, task)
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
    run = Run(run_path(runs_root, preset.name, "policy", f"{agent}-{task}", seed), config)
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
    pair: str,
    *,
    source_policy: Path | str | None = None,
    target_policy: Path | str | None = None,
    episodes: int | None = None,
    seed: int = 0,
    align: str | None = None,
    task: str | None = None,
    runs_root: Path = DEFAULT_RUNS,
    progress: bool = True,
) -> Path:
    """Paired rollouts of both agents' policies on ``task`` (``pved collect-pairs``).

    ``task`` is the pair's training task (default; paper IV.A) or its target task. The
    latter is not the paper's setting (the target agent has no policy for its target
    task before transfer); it is an analysis option: a model trained on such pairs has
    seen the target task's states, so transfer with it says what the training task's
    coverage costs. Both agents of a target-task pair share the parameters a bank is
    matched on (``bank_match_keys``: the hole, the button), as the training task's share
    ``shared_task_keys``. A pair whose envs report no shared parameter (``[tasks]
    shared = []``, e.g. two stock Gymnasium envs) pairs the episodes by seed alone:
    the k-th episodes of both agents start from resets with the same seed.

    ``pair`` is a pair's name or a spec file (:func:`pved.spec.load_pair`)."""
    preset = get_preset(pair)
    pair = preset.name
    cfg = preset.pairing
    # the options checked as the pairing config checks its own fields; the run's config
    # keeps the preset's pairing config (its hash is that of the runs made before)
    with named_options(episodes="--episodes", align="--align", seed="--seed"):
        dataclasses.replace(cfg, **given(episodes=episodes, align=align, seed=seed))
    episodes = cfg.episodes if episodes is None else episodes
    align = cfg.align if align is None else align
    task = preset.training_task if task is None else task
    if task not in (preset.training_task, preset.target_task):
        raise PvedError(
            f"unknown task {task!r} for {pair}: its tasks are {preset.training_task} "
            f"(training) and {preset.target_task} (target)"
        )
    on_training_task = task == preset.training_task
    shared_task_keys = preset.shared_task_keys if on_training_task else preset.bank_match_keys
    src_path = policy_path(preset, preset.source_agent, task, source_policy, runs_root)
    tgt_path = policy_path(preset, preset.target_agent, task, target_policy, runs_root)
    src_id, src_kwargs = env_of(preset, preset.source_agent, task)
    tgt_id, tgt_kwargs = env_of(preset, preset.target_agent, task)
    config = {
        "stage": "pairs",
        "pair": pair,
        "episodes": episodes,
        "seed": seed,
        "align": align,
        "pairing": cfg,
        "source_policy": file_digest(src_path),
        "target_policy": file_digest(tgt_path),
        **spec_identity(preset),
    }
    run_name = align
    if not on_training_task:
        # only then, so the datasets made before the option keep their hashes and places
        config["task"] = task
        run_name = f"{task}-{align}"
    run = Run(run_path(runs_root, pair, "pairs", run_name, seed), config, tensorboard=False)
    out = run.path / "pairs.npz"
    if run.is_done() and out.exists():
        return out
    check_writable("--runs", run.path)
    src_env = make_batched(src_id, cfg.num_envs, **src_kwargs)
    tgt_env = make_batched(tgt_id, cfg.num_envs, **tgt_kwargs)
    src_pol, tgt_pol = load_agent_policy(src_path), load_agent_policy(tgt_path)
    _check_policy(src_pol, src_id, src_env)
    _check_policy(tgt_pol, tgt_id, tgt_env)
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
    header = {
        "pair": pair,
        "source_agent": preset.source_agent,
        "target_agent": preset.target_agent,
        "source_env_id": src_id,
        "target_env_id": tgt_id,
        **spec_identity(preset),
        "source_policy": str(src_path),
        "target_policy": str(tgt_path),
        **env_header(src_env, tgt_env),
        "alignment": align,
        "deterministic_actions": cfg.deterministic,
        "seed": seed,
    }
    # control periods, for alignment by physical time (None for envs without one)
    dt_s, dt_t = getattr(src_env, "dt", None), getattr(tgt_env, "dt", None)
    header.update(dt_source=dt_s, dt_target=dt_t)
    if align in LEARNED_ALIGNMENTS:
        time_only = "subsample"
    elif align == "phase":  # re-paired by phase around the same moment
        time_only = "time" if dt_s is not None and dt_t is not None else "subsample"
    else:
        time_only = align
    alignment = [
        align_steps(time_only, len(e_s.obs), len(e_t.obs), dt_s, dt_t) for e_s, e_t in pairs
    ]
    if align == "dtw":
        alignment, rounds = _dtw_rounds(preset, pairs, alignment, header, seed, progress)
        header["dtw"] = rounds
    if align == "phase":
        alignment, header["phase"] = _phase_alignment(pairs, alignment, header)
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


def _model_rows(pairs: list[EpisodePair], header: dict[str, Any]) -> list[np.ndarray]:
    """Per episode pair, the model inputs ``[robot state, action]`` of both agents."""
    idx_s = np.asarray(header["robot_state_indices_source"])
    idx_t = np.asarray(header["robot_state_indices_target"])
    rows = []
    for e_s, e_t in pairs:
        rows.append(np.concatenate([e_s.obs[:, idx_s], e_s.act], 1).astype(np.float32))
        rows.append(np.concatenate([e_t.obs[:, idx_t], e_t.act], 1).astype(np.float32))
    return rows


def _dtw_rounds(
    preset: PairPreset,
    pairs: list[EpisodePair],
    alignment: list[tuple[np.ndarray, np.ndarray]],
    header: dict[str, Any],
    seed: int,
    progress: bool,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[dict[str, float]]]:
    """Gupta et al. (2017)'s alternation: train the pair's model on the current
    alignment, re-align each episode pair by DTW on the two agents' shared means, repeat
    ``dtw_rounds`` times. Returns the last alignment and per-round statistics (how many
    rows changed partner, the model's validation loss)."""
    cfg = preset.pairing
    config = preset.model_config(cfg.dtw_model, seed=seed, epochs=cfg.dtw_epochs)
    rows = _model_rows(pairs, header)
    state_dims = (
        len(header["robot_state_indices_source"]),
        len(header["robot_state_indices_target"]),
    )
    stats: list[dict[str, float]] = []
    for round_index in range(cfg.dtw_rounds):
        data = pairs_to_dataset(pairs, alignment, shared_task_keys=(), header=header)
        x_s, x_t = data.model_inputs()
        model = fit_model(cfg.dtw_model, x_s, x_t, config, state_dims=state_dims, progress=progress)
        new_alignment = []
        with torch.no_grad():
            for e in range(len(pairs)):
                emb_s = model.shared_source(torch.as_tensor(rows[2 * e])).mean.numpy()
                emb_t = model.shared_target(torch.as_tensor(rows[2 * e + 1])).mean.numpy()
                new_alignment.append(dtw_indices(emb_s, emb_t))
        changed = [
            float(
                np.mean(_partner(old, len(pairs[e][0].obs)) != _partner(new, len(pairs[e][0].obs)))
            )
            for e, (old, new) in enumerate(zip(alignment, new_alignment, strict=True))
        ]
        stats.append({"round": float(round_index + 1), "moved_fraction": float(np.mean(changed))})
        alignment = new_alignment
    return alignment, stats


def _phase_alignment(
    pairs: list[EpisodePair],
    alignment: list[tuple[np.ndarray, np.ndarray]],
    header: dict[str, Any],
) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict[str, Any]]:
    """Re-pair every episode pair of the time alignment by gait phase
    (:func:`pved.pairing.align.phase_indices`). Each agent's gait signal is the first
    principal component of its robot state, standardised over all its episodes' steps;
    its phase is taken per episode. Returns the new alignment and what it did: the share
    of the components' variance, and how far (in source steps) a pair's source step moved
    (mean, and the share of pairs that moved)."""
    stats: dict[str, Any] = {"window": PHASE_WINDOW}
    phases: dict[str, list[np.ndarray]] = {}
    for side, key, column in (("source", "robot_state_indices_source", 0),
                              ("target", "robot_state_indices_target", 1)):  # fmt: skip
        idx = np.asarray(header[key])
        states = [np.asarray(pair[column].obs, dtype=np.float64)[:, idx] for pair in pairs]
        mean, scale, direction, share = first_component(np.concatenate(states))
        stats[f"pc1_variance_{side}"] = share
        phases[side] = [gait_phase(((x - mean) / scale) @ direction) for x in states]
    new_alignment = [
        phase_indices(phases["source"][e], phases["target"][e], base)
        for e, base in enumerate(alignment)
    ]
    moved = np.concatenate(
        [np.abs(new[0] - old[0]) for old, new in zip(alignment, new_alignment, strict=True)]
    )
    stats["moved_fraction"] = float(np.mean(moved > 0))
    stats["mean_source_steps_moved"] = float(moved.mean())
    return new_alignment, stats


def _partner(alignment: tuple[np.ndarray, np.ndarray], length_source: int) -> np.ndarray:
    """For each source step, the mean target step it is paired with (NaN if unpaired)."""
    i_s, i_t = alignment
    total = np.bincount(i_s, weights=i_t, minlength=length_source)
    count = np.bincount(i_s, minlength=length_source)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def default_dataset_path(pair: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0) -> Path:
    preset = get_preset(pair)
    return run_path(runs_root, preset.name, "pairs", preset.pairing.align, seed) / "pairs.npz"


def default_model_path(
    pair: str, model: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0
) -> Path:
    return run_path(runs_root, get_preset(pair).name, "model", model, seed) / "model.pt"


def train_model(
    pair: str,
    model: str = "pved",
    *,
    dataset: Path | str | None = None,
    seed: int = 0,
    epochs: int | None = None,
    runs_root: Path = DEFAULT_RUNS,
    progress: bool = True,
) -> Path:
    """Fit a shared-space model on a paired dataset (``pved train-model``). A dataset
    collected for another pair, agents or spec is refused before the fit."""
    preset = get_preset(pair)
    pair = preset.name
    with named_options(epochs="--epochs", seed="--seed"):
        model_cfg = preset.model_config(model, seed=seed, epochs=epochs)
    data_path = (
        run_file(dataset, "pairs.npz", "dataset")
        if dataset is not None
        else default_dataset_path(pair, runs_root)
    )
    data = load_dataset(data_path)
    data.check_agents(preset.source_agent, preset.target_agent)
    check_dataset_for(preset, data.header, data_path)
    # the envs the pairs were collected on: the training task's unless `--task` chose another
    task = preset.training_task
    for env_task in (preset.training_task, preset.target_task):
        if (
            data.header.get("target_env_id")
            == preset.agent_env(preset.target_agent, env_task).env_id
        ):
            task = env_task
    src_id, src_kwargs = env_of(preset, preset.source_agent, task)
    tgt_id, tgt_kwargs = env_of(preset, preset.target_agent, task)
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
        "pair": pair,
        "model": model,
        "dataset": file_digest(data_path),
        "model_config": model_cfg,
        **spec_identity(preset),
    }
    run = Run(run_path(runs_root, pair, "model", model, seed), config)
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
            "pair": pair,
            "model": model,
            # its digest, not its path: a model names no place on the machine it was made on
            "dataset": file_digest(data_path),
            "source_agent": preset.source_agent,
            "target_agent": preset.target_agent,
            "seed": seed,
            "robot_state_indices_source": data.header["robot_state_indices_source"],
            "robot_state_indices_target": data.header["robot_state_indices_target"],
            **spec_identity(preset),
        },
    )
    last = run.read_metrics()[-1] if run.read_metrics() else {}
    val = {k.removeprefix("val/"): v for k, v in last.items() if k.startswith("val/")}
    collapsed = shared_subspace_collapsed(val)
    if collapsed:
        warnings.warn(
            f"{model} on {pair}: both shared posteriors sit on the prior (validation KL of c "
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
    pair: str,
    *,
    source_policy: Path | str | None = None,
    episodes: int | None = None,
    seed: int = 0,
    runs_root: Path = DEFAULT_RUNS,
) -> Path:
    """Rollouts of the source's target-task policy, matched into Eq. 10 at transfer."""
    preset = get_preset(pair)
    pair = preset.name
    if episodes is not None:
        with named_options(bank_episodes="--episodes"):
            dataclasses.replace(preset.transfer, bank_episodes=episodes)
    check_seed("--seed", seed)
    episodes = preset.transfer.bank_episodes if episodes is None else episodes
    path = policy_path(preset, preset.source_agent, preset.target_task, source_policy, runs_root)
    name, env_kwargs = env_of(preset, preset.source_agent, preset.target_task)
    config = {
        "stage": "bank",
        "env_id": name,
        "episodes": episodes,
        "seed": seed,
        "match_keys": preset.bank_match_keys,
        "source_policy": file_digest(path),
        **spec_identity(preset),
    }
    run = Run(
        run_path(runs_root, pair, "bank", f"{preset.source_agent}-{preset.target_task}", seed),
        config,
        tensorboard=False,
    )
    out = run.path / "bank.npz"
    if run.is_done() and out.exists():
        return out
    check_writable("--runs", run.path)
    env = _eval_env(name, episodes, **env_kwargs)
    policy = load_agent_policy(path)
    _check_policy(policy, name, env)
    run.start()
    bank = build_source_bank(
        env,
        policy,
        episodes,
        preset.bank_match_keys,
        seed=seed,
        # a spec's digest only for a pair of its own: a built-in pair's bank is the bytes it
        # always was, so the transfer runs that hash it keep their configs
        header={"env_id": name, "source_policy": str(path), **spec_identity(preset)},
    )
    save_bank(out, bank)
    run.finish(
        {"bank": str(out), "episodes": episodes, "success_rate": bank.header["success_rate"]}
    )
    return out


def check_model_for(
    preset: PairPreset,
    model: SharedSpaceModel,
    path: Path | str,
    method: str | None = None,
    target_robot_state: Sequence[int] | np.ndarray | None = None,
) -> None:
    """Refuse, in one line, a model made for another pair: its metadata's pair, agents
    and robot-state selection of the target (``target_robot_state``: the target env's,
    when known) against ``preset``'s, its name against ``method`` (when given). A key a
    model file lacks (one made before the key was written) is not checked."""
    meta = model.metadata
    wanted = {
        "pair": preset.name,
        "source_agent": preset.source_agent,
        "target_agent": preset.target_agent,
    }
    for key, want in wanted.items():
        if meta.get(key) not in (None, want):
            raise PvedError(
                f"model {path} was trained for another pair: its {key} is {meta[key]!r}, "
                f"{preset.name}'s is {want!r}"
            )
    _check_spec(preset, meta, f"model {path}")
    if method is not None and model.name != method:
        raise PvedError(f"model {path} is a {model.name!r} model, not {method!r}")
    have = meta.get("robot_state_indices_target")
    if have is not None and target_robot_state is not None:
        if [int(i) for i in have] != [int(i) for i in target_robot_state]:
            raise PvedError(
                f"model {path} reads the target's robot state at {list(have)}, "
                f"the {preset.target_agent} env has it at {list(target_robot_state)}"
            )


def check_bank_for(
    preset: PairPreset, bank: SourceBank, path: Path | str, model: SharedSpaceModel | None = None
) -> None:
    """Refuse, in one line, a source bank made for another pair: its header's env (the
    pair's source agent on its target task), match keys and robot-state selection (that
    of ``model``'s source, when given) against the pair's. A key a bank file lacks is not
    checked."""
    header = bank.header
    want_env = preset.agent_env(preset.source_agent, preset.target_task).env_id
    if header.get("env_id") not in (None, want_env):
        raise PvedError(
            f"source bank {path} was made on {header['env_id']}, {preset.name}'s is {want_env}"
        )
    _check_spec(preset, header, f"source bank {path}")
    keys = header.get("match_keys")
    if keys is not None and list(keys) != list(preset.bank_match_keys):
        raise PvedError(
            f"source bank {path} matches on {list(keys)}, {preset.name} on "
            f"{list(preset.bank_match_keys)}"
        )
    have = header.get("robot_state_indices")
    want = None if model is None else model.metadata.get("robot_state_indices_source")
    if have is not None and want is not None and list(have) != list(want):
        raise PvedError(
            f"source bank {path} holds the source's robot state at {list(have)}, "
            f"the model reads it at {list(want)}"
        )


def _check_spec(preset: PairPreset, header: dict[str, Any], what: str) -> None:
    """Refuse a file made under another version of ``preset``'s spec (or for a built-in
    pair when ``preset`` is a spec of its own, and the reverse): its ``spec`` digest
    (:func:`pved.spec.spec_identity`) against the pair's."""
    want = spec_identity(preset).get("spec")
    have = header.get("spec")
    if have != want:
        raise PvedError(
            f"{what} was made under another spec of {preset.name} (its spec digest "
            f"{have or 'none: a built-in pair'}, this spec's {want or 'none: a built-in pair'})"
        )


def check_dataset_for(preset: PairPreset, header: dict[str, Any], path: Path | str) -> None:
    """Refuse, in one line, a paired dataset collected for another pair or spec, or on
    robot-state indices other than the spec names (its header against ``preset``)."""
    if header.get("pair") not in (None, preset.name):
        raise PvedError(
            f"dataset {path} was collected for pair {header['pair']!r}, not {preset.name!r}"
        )
    _check_spec(preset, header, f"dataset {path}")
    for side, agent in (("source", preset.source_agent), ("target", preset.target_agent)):
        want = preset.robot_state_of(agent)
        have = header.get(f"robot_state_indices_{side}")
        if want is not None and have is not None and [int(i) for i in have] != list(want):
            raise PvedError(
                f"dataset {path} holds the {side}'s robot state at {list(have)}, the spec "
                f"names {list(want)}"
            )


@dataclasses.dataclass(frozen=True)
class TransferSpec:
    """A transfer run resolved from its arguments before anything runs: where it lives,
    the config its hash is taken of, and what it trains on.

    Attributes:
        config: the resolved config (``config.json``; its hash decides whether a run
            directory holds this run).
        run_dir: ``runs_root/<pair>/transfer/<run_name or method>/seed<seed>``.
        env_id: the target agent's target-task env.
        ppo: PPO's config (seed, steps and curve interval applied).
        eval_episodes, final_episodes: episodes per curve point and of the final evaluation.
        train_env_kwargs: env options of the training env (the oracle's full reward).
        shaping_inputs: (model, source bank) of a shaped run; None for ``ppo``/``oracle``.
        beta: the shaping weight (Eq. 10).
    """

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


def eq10_config(pair: str, shaping_action: str = "mean") -> dict[str, Any]:
    """The entries of a shaped transfer run's config that say how Eq. 10 is computed
    (docs/decisions.md, "Transfer (Eq. 10)"): the bank read on the pairs' time base, the
    target action encoded, and the term scaled by the shaped return's std but never
    clipped. Runs made before 2026-12-05 computed otherwise and lack them, so their config
    hashes differ, and a protocol does not take them (``Job.required_config``)."""
    return {
        "bank_time": get_preset(pair).pairing.align,
        "shaping_action": shaping_action,
        "reward_scaling": "term-scaled-unclipped",
    }


def transfer_spec(
    pair: str,
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
    runs_root: Path = DEFAULT_RUNS,
    run_name: str | None = None,
    shaping_start: int = 0,
    shaping_form: str = "eq10",
    shaping_action: str = "mean",
) -> TransferSpec:
    """The :class:`TransferSpec` of ``transfer(...)`` with the same arguments (see there).
    Reads the model and bank only to hash them; a missing one raises :class:`PvedError`."""
    check_shaping_form(shaping_form)  # before any file is looked for
    check_shaping_action(shaping_action)
    check_int("--shaping-start", shaping_start, low=0)
    preset = get_preset(pair)
    pair = preset.name
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
    name, env_kwargs = env_of(preset, preset.target_agent, preset.target_task)
    config: dict[str, Any] = {
        "stage": "transfer",
        "pair": pair,
        "method": method,
        "env_id": name,
        "ppo": ppo,
        "eval_episodes": eval_episodes,
        "final_eval_episodes": final_episodes,
        **spec_identity(preset),
    }
    shaping_inputs: tuple[Path, Path] | None = None
    train_env_kwargs: dict[str, Any] = dict(env_kwargs)
    if method == ORACLE:
        if not name.startswith("pved/"):
            raise PvedError(
                f"the oracle trains on a pved env's full reward (reward='full'); {name} has "
                "no such variant"
            )
        train_env_kwargs["reward"] = "full"
        config["train_reward"] = "full"
    elif method != NO_TRANSFER:
        model_class(method)  # an unknown method name fails here, before any file check
        m_path = (
            run_file(model_path, "model.pt", "model")
            if model_path
            else default_model_path(pair, method, runs_root)
        )
        b_path = (
            run_file(bank_path, "bank.npz", "source bank")
            if bank_path
            else (
                run_path(runs_root, pair, "bank", f"{preset.source_agent}-{preset.target_task}", 0)
                / "bank.npz"
            )
        )
        for what, p in (("model", m_path), ("source bank", b_path)):
            if not p.exists():
                raise PvedError(f"{what} not found: {p} (run the earlier stages first)")
        shaping_inputs = (m_path, b_path)
        config.update(beta=beta, model=file_digest(m_path), bank=file_digest(b_path))
        config.update(eq10_config(pair, shaping_action))
        # both only when set, so the runs made before they existed keep their config hashes
        if shaping_start:
            config["shaping_start"] = shaping_start
        if shaping_form != "eq10":
            config["shaping_form"] = shaping_form
    if shaping_start and shaping_inputs is None:
        raise PvedError(f"a shaping start needs a shaping method; {method!r} has no shaping term")
    if shaping_form != "eq10" and shaping_inputs is None:
        raise PvedError(f"a shaping form needs a shaping method; {method!r} has no shaping term")
    return TransferSpec(
        config=config,
        run_dir=run_path(runs_root, pair, "transfer", run_name or method, seed),
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
    )


def transfer(
    pair: str,
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
    runs_root: Path = DEFAULT_RUNS,
    run_name: str | None = None,
    progress: bool = True,
    shaping_start: int = 0,
    shaping_form: str = "eq10",
    shaping_action: str = "mean",
    checkpoint_every_s: float | None = CHECKPOINT_SECONDS,
) -> dict[str, Any]:
    """PPO of the target agent on the target task (``pved transfer``); returns
    ``result.json``.

    The run lives in ``runs_root/<pair>/transfer/<run_name or method>/seed<seed>``;
    a ``run_name`` keeps apart runs of one method with different betas, models or banks.

    ``method`` is a model name (``pved``, a variant, ``gupta2017``: the target agent's
    restricted reward plus the Eq. 10 shaping term of that model), ``ppo`` (the
    restricted reward alone) or ``oracle`` (the source's full reward, no shaping: what
    the target could do if the reward told it everything). Evaluation always uses the
    target task's default env, so every method is measured alike. ``shaping_start``
    (env steps; not in the paper) holds the shaping term at 0 until then;
    ``shaping_form="log1p"`` (not in the paper) shapes with −β·log(1 + D) in place of
    Eq. 10's −β·D (:class:`LatentShaping`). ``shaping_action``: the target action Eq. 10
    encodes, ``"mean"`` (the policy's mean action, as in the pairs and the bank) or
    ``"taken"`` (the sampled exploration action). ``checkpoint_every_s``: wall-clock
    seconds between checkpoints (:func:`train_ppo`; not part of the run's config).

    Everything is checked before the run directory is made: the options, where the run
    goes, and that the model and bank were made for this pair (:func:`check_model_for`,
    :func:`check_bank_for`)."""
    torch.set_num_threads(1)
    check_checkpoint_seconds(checkpoint_every_s, "--checkpoint-seconds")
    preset = get_preset(pair)
    pair = preset.name
    env_kwargs = env_of(preset, preset.target_agent, preset.target_task)[1]
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
    name, ppo, shaping_inputs = spec.env_id, spec.ppo, spec.shaping_inputs
    eval_episodes, final_episodes = spec.eval_episodes, spec.final_episodes
    run = Run(spec.run_dir, spec.config)
    if run.is_done():
        return run.read_result()
    check_writable("--runs", run.path)
    env = make_batched(name, ppo.num_envs, **spec.train_env_kwargs)
    if shaping_inputs is not None:
        model = load_model(shaping_inputs[0])
        check_model_for(preset, model, shaping_inputs[0], method, env.robot_state_indices)
        bank = load_bank(shaping_inputs[1])
        check_bank_for(preset, bank, shaping_inputs[1], model)
        shaping = LatentShaping(
            model,
            bank,
            spec.beta,
            env.robot_state_indices,
            start=spec.shaping_start,
            form=spec.shaping_form,
            time_scale=bank_time_scale(
                preset.pairing.align, bank_dt(bank), getattr(env, "dt", None)
            ),
            action=spec.shaping_action,
        )
        env = ShapedBatchedEnv(env, shaping, preset.bank_match_keys)
    eval_fn = _eval_fn(
        name, eval_episodes, 10**6 + seed, env_kwargs, info_keys=preset.eval_info_keys
    )
    run.start()
    policy = train_ppo(
        env, ppo, run, eval_fn=eval_fn, progress=progress, checkpoint_every_s=checkpoint_every_s
    )
    policy_file = run.path / "policy.pt"
    policy.save(
        policy_file,
        {
            "env_id": name,
            "seed": seed,
            "method": method,
            "steps": ppo.total_steps,
            "pved_version": __version__,
        },
    )
    final = evaluate_policy(
        policy,
        _eval_env(name, final_episodes, **env_kwargs),
        episodes=final_episodes,
        seed=2 * 10**6 + seed,
        info_keys=preset.eval_info_keys,
    )
    return run.finish(
        {
            "method": method,
            "seed": seed,
            "steps": ppo.total_steps,
            "policy": str(policy_file),
            **{f"final/{k}": v for k, v in final.items()},
        }
    )


def evaluate(
    policy_path: Path | str,
    env_name: str | None = None,
    *,
    episodes: int = 500,
    seed: int = 0,
    reward: str | None = None,
    pair: str | None = None,
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
        preset = get_preset(pair)
        agent, task = preset.target_agent, preset.target_task
        if env_name is not None:
            found = [e for e in preset.envs if e.env_id == env_name]
            if not found:
                ids = ", ".join(dict.fromkeys(e.env_id for e in preset.envs))
                raise PvedError(f"env {env_name!r} is not one of {preset.name}'s: {ids}")
            agent, task = found[0].agent, found[0].task
        env_name, env_kwargs = env_of(preset, agent, task)
        info_keys = preset.eval_info_keys
    elif env_name is None:
        raise PvedError("evaluate needs --env or --pair")
    elif env_name.startswith("pved/"):
        info_keys = preset_for_agent(get_entry(env_name).agent).eval_info_keys
    policy = load_agent_policy(run_file(policy_path, "policy.pt", "policy"))
    env = _eval_env(env_name, episodes, **env_kwargs, **({"reward": reward} if reward else {}))
    _check_policy(policy, env_name, env)
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
    "check_bank_for",
    "check_model_for",
    "collect_pairs",
    "evaluate",
    "np",
    "train_model",
    "train_policy",
    "transfer",
]


# ---------------------------------------------------------------------------- analysis
def run_file(path: Path | str, name: str, what: str | None = None) -> Path:
    """``path`` itself, or ``path/name`` when ``path`` is a run directory (a stage's
    ``model.pt``, ``bank.npz``, ``pairs.npz``, ``policy.pt``); :class:`PvedError` naming
    ``what`` (default: ``name``) when there is no such file."""
    path = Path(path)
    resolved = path / name if path.is_dir() else path
    if not resolved.is_file():
        where = f"{path} (a directory without {name})" if path.is_dir() else str(path)
        raise PvedError(f"{what or name} not found: {where}")
    return resolved


def _analysis_inputs(
    pair: str, model_path: Path | str, target_policy: Path | str, source_policy: Path | str | None
) -> tuple[PairPreset, SharedSpaceModel, Policy, Policy, str, str]:
    preset = get_preset(pair)
    model = load_model(run_file(model_path, "model.pt"))
    check_model_for(preset, model, model_path)
    src = load_agent_policy(
        policy_path(preset, preset.source_agent, preset.target_task, source_policy)
    )
    tgt = load_agent_policy(run_file(target_policy, "policy.pt"))
    return (
        preset,
        model,
        src,
        tgt,
        preset.agent_env(preset.source_agent, preset.target_task).env_id,
        preset.agent_env(preset.target_agent, preset.target_task).env_id,
    )


def analyze_subspaces(
    pair: str,
    model_path: Path | str,
    target_policy: Path | str,
    out: Path | str,
    *,
    source_policy: Path | str | None = None,
    episodes: int = 6,
    marks: int = 4,
    seed: int = 0,
    target_later_frames: int | None = None,
    later_frame_stride: int | None = None,
    x_groups: int = 2,
) -> dict[str, Any]:
    """``pved tsne``: t-SNE of both agents' shared and individual posterior means along
    target-task rollouts (paper IV.C, Figs. 4–7), frames nearest to marks, and the numbers
    beside them (time correspondence, agent-identity probes) in ``out/numbers.json``.

    For Humanoid → Ant also the paper's Fig. 7 and Fig. 8 additions:

    * ``target_later_frames`` later target frames per mark, ``later_frame_stride`` control
      steps apart (None: :func:`pved.analysis.tsne.default_later_frames` of the pair's
      target agent, 2 for Ant, and ``DEFAULT_LATER_FRAME_STRIDE``);
    * on Curve, where the envs report the torso x, ``fig8_groups.png`` and
      ``numbers["x_split"]``: the target's shared-embedding points in ``x_groups``
      k-means groups, counted before and after the x where the Curve's slope stops rising
      (``CURVE_RAMP_LENGTH``, 12 m). Other tasks have no such landmark and skip it.
    """
    from pved.analysis.tsne import (
        DEFAULT_LATER_FRAME_STRIDE,
        default_later_frames,
        embed_rollouts,
        mark_positions,
        plot_tsne,
        subspace_embeddings,
        subspace_numbers,
        write_x_split,
    )
    from pved.envs.terrain import CURVE_RAMP_LENGTH

    torch.set_num_threads(1)
    # checked before the rollouts, which take the time, and so is where the figures go
    check_int("--episodes", episodes, low=1)
    check_int("--marks", marks, low=0)
    check_seed("--seed", seed)
    check_int("x_groups", x_groups, low=1)
    if target_later_frames is not None:
        check_int("--later-frames", target_later_frames, low=0)
    if later_frame_stride is not None:
        check_int("--later-frame-stride", later_frame_stride, low=1)
    check_writable("--out", out)
    preset, model, src, tgt, src_id, tgt_id = _analysis_inputs(
        pair, model_path, target_policy, source_policy
    )
    # The default follows the target agent (Ant's movement needs several frames, Fig. 7),
    # not the pair's name, so any pair with an Ant target gets it.
    later = (
        default_later_frames(preset.target_agent)
        if target_later_frames is None
        else int(target_later_frames)
    )
    stride = DEFAULT_LATER_FRAME_STRIDE if later_frame_stride is None else int(later_frame_stride)
    data = embed_rollouts(
        model, src, tgt, src_id, tgt_id, episodes, seed, match_keys=preset.bank_match_keys
    )
    out = Path(out)
    # One embedding for the scatters, the marks and the x split, so the groups' centres
    # and the marks are positions in the same picture.
    emb = subspace_embeddings(data, seed)
    figures = plot_tsne(
        data,
        out,
        marks=marks,
        seed=seed,
        embeddings=emb,
        target_later_frames=later,
        later_frame_stride=stride,
    )
    numbers = subspace_numbers(data, seed=seed)
    centres = mark_positions(emb["shared"], marks, seed) if marks > 0 else None
    numbers["marks"] = [] if centres is None else centres.tolist()
    numbers["mark_frames"] = {"target_later_frames": later, "later_frame_stride": stride}
    if preset.target_task == "Curve":
        split = write_x_split(
            data, emb["shared"], out, CURVE_RAMP_LENGTH, groups=x_groups, seed=seed, marks=centres
        )
        if split is not None:
            numbers["x_split"] = split
            figures.append(out / "fig8_groups.png")
    atomic_write_json(out / "numbers.json", numbers)
    return {"figures": [str(p) for p in figures], "numbers": numbers}


def bound(
    pair: str,
    model_path: Path | str,
    target_policy: Path | str,
    *,
    source_policy: Path | str | None = None,
    episodes: int = 10,
    quantile: float = 0.95,
    gamma: float = 0.99,
    seed: int = 0,
) -> dict[str, Any]:
    """``pved bound``: Theorem 1 and Corollary 1 (paper III.E) estimated on rollouts of the
    source and the transferred target, beside the measured gaps."""
    from pved.analysis.bound import theorem1_bound

    torch.set_num_threads(1)
    check_int("--episodes", episodes, low=1)
    check_number("--quantile", quantile, low=0.0, high=1.0)
    check_number("--gamma", gamma, low=0.0, high=1.0)
    check_seed("--seed", seed)
    preset, model, src, tgt, src_id, tgt_id = _analysis_inputs(
        pair, model_path, target_policy, source_policy
    )
    result = theorem1_bound(
        model,
        src,
        tgt,
        src_id,
        tgt_id,
        episodes,
        seed,
        quantile=quantile,
        gamma=gamma,
        match_keys=preset.bank_match_keys,
        time_scale=bank_time_scale(preset.pairing.align, env_dt(src_id), env_dt(tgt_id)),
    )
    return {"summary": result.summary(), **result.as_dict()}
