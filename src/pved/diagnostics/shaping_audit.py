"""What Eq. 10's term does at the start of a transfer run (``pved audit-shaping``).

A transfer run starts from a fresh PPO policy (exploration std exp(init_log_std) = 1 on
[−1, 1] actuators). On that policy's rollouts on the target task, with the pair's model
and source bank, this module measures, on the same target states:

- **which action is encoded**: D = KL(q_φS(c|s_S,a_S) ‖ q_φT(c|s_T,a_T)) with a_T the
  policy's mean action (what the pairs and the bank record) and with the sampled, clipped
  action the env is stepped with;
- **where PPO's reward clip binds**: PPO divides rewards by the running std σ of the
  discounted return and clips them to ±clip. The share of steps the clip cut when it
  acted on env reward + shaping (before 2026-12-05), the share it cuts now that it acts
  on the env part alone (σ still of the shaped return, the term never clipped,
  ``pved.rl.ppo``), plain PPO's share, and, for the alternative of a σ of the env return
  alone, the share of steps where the term alone would exceed the clip;
- **the term's size**: β·D against |r_env| per step;
- **how much of D the action can remove**: on a sample of the rollout's rows, D
  minimised over the target action in its box (:func:`min_over_actions`), the target's
  state and the source's code held: what is left is the part of D no action at that
  state can remove (the state, or the moment in the source's episode, does not match),
  the part a loss on the action (``pved-align``) cannot reach.

The rollout is a fresh policy's by default: a reading of where training starts, where the
term is largest, not of a whole run (a run's ``rollout/clipped_share`` logs the clip over
it). ``--policy`` rolls out a trained policy instead (its own observation normaliser,
frozen), to read the same at the states a run ends in.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved.checks import check_int, check_number, check_seed, check_writable, named_options
from pved.envs import make_batched
from pved.errors import PvedError
from pved.models.base import SharedRep, SharedSpaceModel
from pved.record_paths import record_path
from pved.rl.networks import ActorCritic, ObsNormalizer, RunningMeanStd
from pved.rl.policy import Policy
from pved.rl.ppo import PPOConfig
from pved.transfer.shaping import LatentShaping, task_params
from pved.transfer.source_bank import SourceBank

QUANTILES = (0.5, 0.95)
MIN_STARTS = 4
"""Starts of the search over actions: the policy's mean action and uniform random ones."""
MIN_ITERS = 200
"""Projected Adam steps per start (lr :data:`MIN_LR`) on log(1 + D)."""
MIN_LR = 0.05


def distance_stats(distance: np.ndarray) -> dict[str, float]:
    """Mean, median and 95% quantile of per-row distances (R,)."""
    return {
        "mean": float(distance.mean()),
        **{f"q{round(q * 100)}": float(np.quantile(distance, q)) for q in QUANTILES},
    }


@torch.no_grad()
def matched_and_shuffled(
    model: SharedSpaceModel, x_s: np.ndarray, x_t: np.ndarray, rows: int, seed: int
) -> dict[str, dict[str, float]]:
    """D of Eq. 10 on ``rows`` seeded samples of the paired rows x_s (M, D_S), x_t (M, D_T),
    matched and with the target side shuffled: ``{"matched": stats, "shuffled": stats}``
    (:func:`distance_stats`)."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False)
    shuffled = rng.permutation(pick)
    source = torch.as_tensor(x_s[pick], dtype=torch.float32)
    out = {}
    for name, target_rows in (("matched", pick), ("shuffled", shuffled)):
        target = torch.as_tensor(x_t[target_rows], dtype=torch.float32)
        out[name] = distance_stats(model.shaping(source, target).double().numpy())
    return out


def initial_policy(obs_dim: int, act_dim: int, low: Any, high: Any, ppo: PPOConfig) -> Policy:
    """The policy a transfer run with ``ppo`` starts from (its seed's initial weights)."""
    net = ActorCritic(obs_dim, act_dim, ppo.hidden_sizes, ppo.activation, ppo.init_log_std)
    net.init_weights(ppo.seed)
    norm = ObsNormalizer(obs_dim, ppo.normalize_obs, ppo.obs_clip)
    return Policy(net, norm, np.asarray(low), np.asarray(high), {"seed": ppo.seed})


def min_over_actions(
    model: SharedSpaceModel,
    source: SharedRep,
    state: np.ndarray,
    first: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    seed: int = 0,
) -> np.ndarray:
    """The least D of Eq. 10 found over target actions in the box [low, high], the target's
    robot state (R, S) and the source's code (``source``, (R, K)) held: projected Adam on
    log(1 + D) from ``first`` (R, A) (the policy's mean action) and from
    :data:`MIN_STARTS` − 1 uniform random actions (seeded), :data:`MIN_ITERS` steps each;
    the least D each row reached, counting ``first`` itself. (R,). An upper bound on the
    true minimum (a local search), so the share of D it shows removable is a lower
    bound."""
    lo = torch.as_tensor(np.asarray(low, dtype=np.float32))
    hi = torch.as_tensor(np.asarray(high, dtype=np.float32))
    s = torch.as_tensor(np.asarray(state, dtype=np.float32))
    gen = torch.Generator().manual_seed(seed)

    def distance(action: torch.Tensor) -> torch.Tensor:
        return model.shaping_between(source, model.shared_target(torch.cat([s, action], 1)))

    start = torch.clamp(torch.as_tensor(np.asarray(first, dtype=np.float32)), lo, hi)
    with torch.no_grad():
        best = distance(start)
    for k in range(MIN_STARTS):
        init = start if k == 0 else lo + (hi - lo) * torch.rand(start.shape, generator=gen)
        action = init.clone().requires_grad_(True)
        opt = torch.optim.Adam([action], lr=MIN_LR)
        for _ in range(MIN_ITERS):
            opt.zero_grad()
            torch.log1p(distance(action)).sum().backward()
            opt.step()
            with torch.no_grad():
                action.copy_(torch.clamp(action, lo, hi))
        with torch.no_grad():
            best = torch.minimum(best, distance(action))
    return best.numpy().astype(np.float64)


def rollout_terms(
    env_id: str,
    model: SharedSpaceModel,
    bank: SourceBank,
    match_keys: tuple[str, ...],
    ppo: PPOConfig,
    steps: int,
    time_scale: float = 1.0,
    policy: Policy | None = None,
    min_rows: int = 0,
) -> dict[str, np.ndarray]:
    """Roll out the initial policy of ``ppo`` (or ``policy``, its normaliser frozen) for
    ``steps`` env steps (over its ``num_envs`` copies; the env is stepped with sampled
    actions, as in training) and return per step (T, N): ``env_reward``, ``d_mean`` and
    ``d_taken`` (D of Eq. 10 with the mean and with the sampled action, β = 1) and
    ``done``; with ``min_rows`` > 0 also ``d_min_rows`` (R,) and ``d_min`` (R,): D at the
    mean action and D minimised over actions (:func:`min_over_actions`) on R =
    ``min_rows`` rows drawn from the rollout (seeded by ``ppo.seed``)."""
    env = make_batched(env_id, ppo.num_envs)
    try:
        n = env.num_envs
        space = env.single_action_space
        obs_dim, act_dim = int(env.single_observation_space.shape[0]), int(space.shape[0])
        trained = policy is not None
        if policy is None:
            policy = initial_policy(obs_dim, act_dim, space.low, space.high, ppo)
        elif policy.act_dim != act_dim:
            raise PvedError(f"the policy acts in {policy.act_dim} dims, {env_id} in {act_dim}")
        shaping = LatentShaping(model, bank, 1.0, env.robot_state_indices, time_scale=time_scale)
        rng = np.random.default_rng(ppo.seed)
        obs, info = env.reset(seed=ppo.seed)
        if not trained:
            policy.obs_normalizer.update(np.asarray(obs, dtype=np.float64))
        episode = bank.match(task_params(info, match_keys, n), rng)
        t = np.zeros(n, dtype=np.int64)
        rows = -(-steps // n)
        out = {k: np.zeros((rows, n)) for k in ("env_reward", "d_mean", "d_taken", "done")}
        # what the search over actions needs of each row: state, mean action, source code
        kept: dict[str, list[np.ndarray]] = {"state": [], "mean": [], "code": [], "logvar": []}
        for i in range(rows):
            mean = policy.act(obs, deterministic=True)
            taken = policy.act(obs, deterministic=False, rng=rng)
            out["d_mean"][i] = -shaping.reward(obs, mean, episode, t)
            out["d_taken"][i] = -shaping.reward(obs, taken, episode, t)
            if min_rows:
                q_s = shaping.encoded(n).lookup(episode, t, shaping.time_scale)
                kept["state"].append(np.asarray(obs)[:, shaping.robot_state_indices])
                kept["mean"].append(np.asarray(mean))
                kept["code"].append(q_s.mean.numpy())
                if q_s.logvar is not None:
                    kept["logvar"].append(q_s.logvar.numpy())
            obs, reward, terminated, truncated, info = env.step(taken)
            done = np.asarray(terminated, bool) | np.asarray(truncated, bool)
            out["env_reward"][i], out["done"][i] = reward, done
            if not trained:
                policy.obs_normalizer.update(np.asarray(obs, dtype=np.float64))
            t += 1
            if done.any():
                t[done] = 0
                episode[done] = bank.match(task_params(info, match_keys, n)[done], rng)
        if min_rows:
            pick = np.random.default_rng(ppo.seed).permutation(rows * n)[:min_rows]
            rows_of = {k: np.concatenate(v)[pick] for k, v in kept.items() if v}
            source = SharedRep(
                torch.as_tensor(rows_of["code"]),
                torch.as_tensor(rows_of["logvar"]) if "logvar" in rows_of else None,
            )
            out["d_min_rows"] = out["d_mean"].reshape(-1)[pick]
            out["d_min"] = min_over_actions(
                model, source, rows_of["state"], rows_of["mean"], space.low, space.high, ppo.seed
            )
        return out
    finally:
        env.close()


def clip_shares(
    env_reward: np.ndarray,
    shaping: np.ndarray,
    done: np.ndarray,
    gamma: float = 0.99,
    clip: float = 10.0,
) -> dict[str, float]:
    """Share of steps PPO's ±``clip`` binds on, per treatment of a shaped reward.

    Args:
        env_reward, shaping, done: (T, N) per step (shaping is −β·D, ≤ 0).

    Returns:
        ``sum``: steps whose (r_env + shaping)/σ_sum lies beyond ±``clip``, σ_sum the
        running std of the shaped return: what the clip cut before 2026-12-05;
        ``env_part``: steps whose r_env/σ_sum lies beyond it, what it cuts today (the
        term is never clipped); ``env``: r_env/σ_env with σ_env of the env return
        alone, plain PPO's share on these rewards; ``shaping_over_clip``: steps where
        shaping/σ_env exceeds ``clip``, the size the term would take were σ taken of the
        env return alone (the alternative not taken); ``env_weight``: the mean of
        σ_env/σ_sum, how much smaller the env reward is in PPO's units than plain PPO
        makes it (the ratio of env reward to term is the same either way).
    """
    if not (env_reward.shape == shaping.shape == done.shape) or env_reward.ndim != 2:
        raise PvedError("clip_shares needs equal (T, N) arrays")
    hits = {"sum": 0, "env_part": 0, "env": 0, "shaping_over_clip": 0}
    scales: dict[str, list[float]] = {"sum": [], "env": []}
    for key, stream in (("sum", env_reward + shaping), ("env", env_reward)):
        rms, acc = RunningMeanStd(()), np.zeros(env_reward.shape[1])
        for i in range(len(stream)):
            acc = acc * gamma + stream[i]
            rms.update(acc)
            scale = math.sqrt(float(rms.var) + 1e-8)
            scales[key].append(scale)
            hits[key] += int(np.count_nonzero(np.abs(stream[i] / scale) > clip))
            if key == "sum":
                hits["env_part"] += int(np.count_nonzero(np.abs(env_reward[i] / scale) > clip))
            else:
                big = np.abs(shaping[i]) / scale > clip
                hits["shaping_over_clip"] += int(np.count_nonzero(big))
            acc[done[i].astype(bool)] = 0.0
    shares = {k: v / env_reward.size for k, v in hits.items()}
    shares["env_weight"] = float(np.mean(np.divide(scales["env"], scales["sum"])))
    return shares


def _quantiles(x: np.ndarray) -> dict[str, float]:
    return {
        "median": float(np.median(x)),
        "mean": float(np.mean(x)),
        "q90": float(np.quantile(x, 0.9)),
        "max": float(np.max(x)),
    }


def audit(
    terms: dict[str, np.ndarray], betas: Sequence[float], gamma: float, clip: float
) -> dict[str, Any]:
    """The audit's numbers from :func:`rollout_terms`' arrays, for each β in ``betas``
    (the treatments' clip shares and the term's share of |r_env|), with a_T the mean
    action (as Eq. 10 is computed now)."""
    if not betas or any(not (math.isfinite(b) and b > 0) for b in betas):
        raise PvedError(f"betas must be positive numbers, got {list(betas)}")
    env_abs = float(np.mean(np.abs(terms["env_reward"])))
    by_beta = {}
    for beta in betas:
        shaping = -beta * terms["d_mean"]
        by_beta[f"{beta:g}"] = {
            **clip_shares(terms["env_reward"], shaping, terms["done"], gamma, clip),
            "term_over_env": float(np.mean(-shaping)) / max(env_abs, 1e-12),
        }
    ratio = terms["d_taken"] / np.maximum(terms["d_mean"], 1e-12)
    result: dict[str, Any] = {
        "steps": int(terms["env_reward"].size),
        "d_mean_action": _quantiles(terms["d_mean"]),
        "d_taken_action": _quantiles(terms["d_taken"]),
        "taken_over_mean_median": float(np.median(ratio)),
        "env_reward_abs_mean": env_abs,
        "by_beta": by_beta,
    }
    if "d_min" in terms:
        at_mean, least = terms["d_min_rows"], terms["d_min"]
        result["removable_by_action"] = {
            "rows": int(least.size),
            "d_mean_action": _quantiles(at_mean),
            "d_min_over_actions": _quantiles(least),
            # per row, the share of D the best action found removes (a lower bound)
            "share_median": float(np.median(1.0 - least / np.maximum(at_mean, 1e-12))),
        }
    return result


def audit_transfer_start(
    env_id: str,
    model: SharedSpaceModel,
    bank: SourceBank,
    match_keys: tuple[str, ...],
    ppo: PPOConfig,
    *,
    steps: int,
    betas: Sequence[float],
    time_scale: float = 1.0,
    seed: int = 2000,
    policy: Policy | None = None,
    min_rows: int = 0,
) -> dict[str, Any]:
    """:func:`audit` of :func:`rollout_terms` for a transfer run of ``ppo`` with ``seed``
    (or of ``policy``), with D minimised over actions on ``min_rows`` rows."""
    if steps <= 0:
        raise PvedError(f"steps must be > 0, not {steps}")
    torch.set_num_threads(1)
    ppo = dataclasses.replace(ppo, seed=seed)
    terms = rollout_terms(
        env_id, model, bank, match_keys, ppo, steps, time_scale, policy=policy, min_rows=min_rows
    )
    return {
        "env_id": env_id,
        "seed": seed,
        "time_scale": time_scale,
        **audit(terms, betas, ppo.gamma, ppo.reward_clip),
    }


def audit_pair(
    pair: str,
    model_path: Path | str,
    bank_path: Path | str,
    *,
    steps: int = 32_768,
    betas: Sequence[float] | None = None,
    seed: int = 2000,
    policy_path: Path | str | None = None,
    min_rows: int = 2048,
    out: Path | str | None = None,
) -> dict[str, Any]:
    """``pved audit-shaping``: :func:`audit_transfer_start` on ``pair``'s target task with
    its transfer PPO config, alignment and β grid (default), of a fresh policy or of the
    trained one at ``policy_path``, with D minimised over actions on ``min_rows`` rows (0:
    not), written to ``out`` (JSON, atomically) when given."""
    from pved.envs import env_id
    from pved.models import load_model
    from pved.pair import resolve_pair
    from pved.rl.policy import load_policy
    from pved.run_layout import check_bank_for, check_model_for
    from pved.runs import atomic_write_json
    from pved.spec import get_preset
    from pved.transfer.source_bank import bank_dt, bank_time_scale, load_bank

    preset = get_preset(pair)
    betas = tuple(preset.beta_grid_for("pved") if betas is None else betas)
    check_int("--steps", steps, low=1)
    check_int("--min-rows", min_rows, low=0)
    check_seed("--seed", seed)
    if not betas:
        raise PvedError("--betas must be one or more positive numbers, got none")
    for beta in betas:
        check_number("--betas", beta, low=0.0, low_open=True)
    if out is not None:
        check_writable("--out", out, directory=False)
    model, bank = load_model(Path(model_path)), load_bank(Path(bank_path))
    policy = None if policy_path is None else load_policy(Path(policy_path))
    name = env_id(preset.target_agent, preset.target_task)
    probe = make_batched(name, 1)
    dt_target = getattr(probe, "dt", None)
    resolved = resolve_pair(preset)
    check_model_for(resolved, model, model_path, target_robot_state=probe.robot_state_indices)
    check_bank_for(resolved, bank, bank_path, model)
    probe.close()
    result = {
        "pair": pair,
        "model": record_path(model_path),
        "bank": record_path(bank_path),
        **audit_transfer_start(
            name,
            model,
            bank,
            preset.bank_match_keys,
            preset.transfer.ppo,
            steps=steps,
            betas=betas,
            time_scale=bank_time_scale(preset.pairing.align, bank_dt(bank), dt_target),
            seed=seed,
            policy=policy,
            min_rows=min(min_rows, steps),
        ),
    }
    if policy_path is not None:
        result["policy"] = record_path(policy_path)
    if out is not None:
        atomic_write_json(Path(out), result)
    return result


def likelihood_reading(
    pair: str,
    dataset_path: Path | str,
    *,
    seed: int = 0,
    epochs: int | None = None,
    rows: int = 4000,
    runs_root: Path | str,
    out: Path | str | None = None,
) -> dict[str, Any]:
    """``pved audit-likelihood``: the decoder likelihood's effect on Eq. 10's scale.

    Fits the pair's PVED twice on the same pairs and seed, with the learned per-dimension
    decoder variance (pved's reading, floored at std ``min_decoder_std``) and with a unit
    variance, and reports D on matched and on shuffled training pairs
    (:func:`matched_and_shuffled`) for each, with the shared posteriors' mean std. The
    models are kept under ``runs_root/<pair>/likelihood/<variance>/seed<seed>``."""
    from pved.models import PVEDConfig
    from pved.models.train import train_model as fit_model
    from pved.pairing.dataset import load_dataset
    from pved.runs import Run, atomic_write_json, run_path
    from pved.spec import get_preset

    preset = get_preset(pair)
    with named_options(epochs="--epochs", seed="--seed"):
        base = preset.model_config("pved", seed=seed, epochs=epochs)
    if not isinstance(base, PVEDConfig):
        raise PvedError(f"{pair}'s pved config is not a PVEDConfig")
    check_int("rows", rows, low=1)
    if out is not None:
        check_writable("--out", out, directory=False)
    runs = {v: run_path(Path(runs_root), pair, "likelihood", v, seed) for v in ("learned", "unit")}
    for path in runs.values():
        check_writable("--runs", path)
    data = load_dataset(Path(dataset_path))
    data.check_agents(preset.source_agent, preset.target_agent)
    x_s, x_t = data.model_inputs()
    result: dict[str, Any] = {"pair": pair, "dataset": record_path(dataset_path), "seed": seed}
    for variance, path in runs.items():
        cfg = dataclasses.replace(base, decoder_variance=variance)
        run = Run(
            path, {"stage": "likelihood", "pair": pair, "model_config": cfg}, tensorboard=False
        )
        run.start()
        model = fit_model("pved", x_s, x_t, cfg, run, state_dims=data.state_dims)
        model.eval()
        pick = np.random.default_rng(seed).choice(len(x_s), min(rows, len(x_s)), replace=False)
        with torch.no_grad():
            q_s = model.shared_source(torch.as_tensor(x_s[pick], dtype=torch.float32))
        std = None if q_s.logvar is None else float(torch.exp(0.5 * q_s.logvar).mean())
        result[variance] = {
            **matched_and_shuffled(model, x_s, x_t, rows, seed),
            "shared_std_mean": std,
        }
        run.finish({"shared_std_mean": std})
    if out is not None:
        atomic_write_json(Path(out), result)
    return result
