"""The decoded prior as a policy: what `pved-prior` pulls the target towards, acted out.

`pved-prior` (docs/decisions/transfer.md) pulls the target's mean action towards
a_prior, the action part of Eq. 8's c-only decoder p_θ'S(x_T | c) at the source's shared
code of the matched bank row. a_prior depends on the bank row alone, not on the target's
own state: it is an open-loop plan, one per matched source episode. Acting it out on the
target task says how good a teacher it is: a prior that solves the task could raise the
learning curve from its first steps (a jump-start); one that does not can only help by
where it leaves the policy once it fades, which is what the reacher screen showed.

Beside it, in the same run and on the same reset seeds, two peers with no knowledge of
the source: the zero action and uniformly random actions.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pved.config import EVAL_NUM_ENVS
from pved.envs import BatchedEnv, make_batched
from pved.errors import PvedError
from pved.models.registry import load_model
from pved.pair import Pair, resolve_pair
from pved.rl.evaluate import evaluate_policy
from pved.run_layout import check_bank_for, check_model_for
from pved.runs import run_file
from pved.transfer.prior_guide import check_prior_model
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import bank_dt, bank_time_scale, load_bank


class _Acting:
    """An :class:`~pved.rl.policy.Actor` that acts by ``fn(obs, rng)``."""

    def __init__(
        self,
        fn: Callable[[np.ndarray, np.random.Generator | None], np.ndarray],
        obs_dim: int,
        act_dim: int,
    ) -> None:
        self.fn, self._obs_dim, self._act_dim = fn, obs_dim, act_dim

    @property
    def obs_dim(self) -> int:
        return self._obs_dim

    @property
    def act_dim(self) -> int:
        return self._act_dim

    def act(
        self,
        obs: np.ndarray,
        deterministic: bool = True,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        del deterministic
        return self.fn(obs, rng)


def prior_policy(
    pair: str | Path | Pair,
    model_path: Path | str,
    bank_path: Path | str,
    *,
    episodes: int = 200,
    seed: int = 0,
) -> dict[str, Any]:
    """Success rate, return and the pair's metric of three policies on the target task:
    the decoded prior of ``model_path`` (a PVED model) over the source bank ``bank_path``,
    the zero action and uniform random actions, each for ``episodes`` episodes from the
    same reset seeds (``seed``). Returns ``{"prior": stats, "zero": ..., "random": ...}``
    and a ``summary`` table."""
    if not isinstance(episodes, int) or episodes < 1:
        raise PvedError(f"--episodes must be a positive integer, got {episodes!r}")
    pair = resolve_pair(pair)
    model_file, bank_file = run_file(model_path, "model.pt"), run_file(bank_path, "bank.npz")
    model, bank = load_model(model_file), load_bank(bank_file)
    check_prior_model(type(model))
    name, kwargs = pair.target_env

    def fresh() -> BatchedEnv:
        return make_batched(name, max(1, min(EVAL_NUM_ENVS, episodes)), **kwargs)

    env = fresh()
    # the pair's metric keys and the env's own measures (``metric_*``: e.g. reacher's
    # end-effector-to-button distance), read at each episode's last step
    env.reset(seed=seed)
    probe = env.step(np.zeros((env.num_envs, *env.single_action_space.shape)))[4]
    measures = tuple(sorted(k for k in probe if k.startswith("metric_")))
    info_keys = tuple(dict.fromkeys((*pair.preset.eval_info_keys, *measures)))
    check_model_for(pair, model, model_file, target_robot_state=env.robot_state_indices)
    check_bank_for(pair, bank, bank_file, model)
    shaping = LatentShaping(
        model,
        bank,
        1.0,
        env.robot_state_indices,
        form="prior",
        time_scale=bank_time_scale(
            pair.preset.pairing.align, bank_dt(bank), getattr(env, "dt", None)
        ),
        action="taken",
        align_anneal=1.0,
    )
    shaped = ShapedBatchedEnv(env, shaping, pair.preset.bank_match_keys)
    space = env.single_action_space
    low, high = np.asarray(space.low), np.asarray(space.high)
    obs_dim, act_dim = int(env.single_observation_space.shape[0]), len(low)

    def prior(obs: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        context = shaped.guide_context()
        assert context is not None  # the prior form always has a guide
        return context

    def zero(obs: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        return np.tile(np.clip(np.zeros_like(low), low, high), (len(obs), 1))

    def uniform(obs: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        assert rng is not None  # evaluate_policy seeds it
        return rng.uniform(low, high, size=(len(obs), act_dim))

    result: dict[str, Any] = {"pair": pair.name, "episodes": episodes, "seed": seed}
    result["prior"] = evaluate_policy(
        _Acting(prior, obs_dim, act_dim), shaped, episodes, seed, info_keys=info_keys
    )
    shaped.close()
    for label, fn in (("zero", zero), ("random", uniform)):
        peer = fresh()
        result[label] = evaluate_policy(
            _Acting(fn, obs_dim, act_dim), peer, episodes, seed, info_keys=info_keys
        )
        peer.close()
    columns = (pair.preset.metric, "return_mean", *(f"{k}_mean" for k in measures))
    lines = ["| policy | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for label in ("prior", "zero", "random"):
        values = (f"{result[label].get(c, float('nan')):.3f}" for c in columns)
        lines.append(f"| {label} | " + " | ".join(values) + " |")
    result["summary"] = "\n".join(lines)
    return result


__all__ = ["prior_policy"]
