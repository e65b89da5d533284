"""The numeric fingerprint: three short, fixed computations whose digests say whether the
code still computes what the records were made with (docs/decisions/at-scale.md, "The
numeric fingerprint").

- ``ppo``: PPO (:func:`pved.rl.ppo.train_ppo`, numpy backend, as every run trains) on
  Reacher3 Reach, 2048 env steps, seed 0; its trained networks and normaliser, and the
  returns of a deterministic evaluation. MuJoCo's stepping is in it.
- ``pved-fit``: PVED (Eq. 9) fitted for a few epochs to a generated paired dataset (two
  views of one hidden variable), as the model stage fits (:func:`pved.models.train.
  train_model`); its parameters and its mean loss parts (Eqs. 2-8) after.
- ``shaped``: PPO on Reacher4 Push under Eq. 10's term (:class:`pved.transfer.shaping.
  ShapedBatchedEnv`, the paper's form, the policy's mean action encoded) from an untrained
  PVED and a generated source bank, 1024 env steps; its trained networks and the returns
  of a deterministic evaluation. Independent of ``pved-fit``, so that a change to the
  models' training shows in that stage alone.

Each digest is :func:`pved.runs.state_digest` of the exact values (floats by ``repr``):
one torch thread and one BLAS thread make them exact on one machine, and pved's pinned
kernels (:mod:`pved.blas`) across x86-64 machines with AVX2. Their pins are
``src/pved/fingerprint_pins.json``; the id a run records is
:func:`pved.provenance.fingerprint_id` of the pinned digests.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from pved.blas import loaded_kernel, loaded_mkl_branch, loaded_numpy_simd
from pved.envs import make_batched
from pved.models import PVED, ModelDims, PVEDConfig
from pved.models.train import evaluate_model, single_thread, train_model
from pved.provenance import FINGERPRINT_PINS, fingerprint_id, numeric_stack, read_pins
from pved.rl.evaluate import evaluate_policy
from pved.rl.policy import Policy
from pved.rl.ppo import PPOConfig, train_ppo
from pved.runs import state_digest
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank

SOURCE_ENV = "pved/Reacher3Reach-v0"
SHAPED_ENV = "pved/Reacher4Push-v0"
#: Reacher3's robot state (11) and action (3): the generated bank's and dataset's source rows
SOURCE_DIMS = (11, 3)
#: Reacher4's robot state (14) and action (4)
TARGET_DIMS = (14, 4)
#: small networks and rollouts: the digests must take seconds, not what a run takes
PPO = PPOConfig(
    total_steps=2048,
    num_envs=4,
    steps_per_env=64,
    epochs=2,
    minibatch_size=128,
    hidden_sizes=(32, 32),
    checkpoint_every=0,
    seed=0,
)
MODEL = PVEDConfig(
    epochs=3,
    batch_size=64,
    hidden=32,
    shared_dim=4,
    individual_dim=2,
    consistency_warmup_epochs=1.0,
    seed=0,
)


def _policy_digest(policy: Policy, env_id: str) -> str:
    """The policy's networks and normaliser, and four deterministic episodes' returns."""
    scores = evaluate_policy(policy, make_batched(env_id, 2), episodes=4, seed=7)
    return state_digest(
        {
            "actor_critic": policy.net.state_dict(),
            "obs_normalizer": policy.obs_normalizer.state_dict(),
            "eval": {k: float(v) for k, v in sorted(scores.items())},
        }
    )


def ppo_digest() -> str:
    """Digest of a short PPO run on Reacher3 Reach."""
    policy = train_ppo(make_batched(SOURCE_ENV, PPO.num_envs), PPO, progress=False)
    return _policy_digest(policy, SOURCE_ENV)


def paired_rows(rows: int = 512, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A generated paired dataset: source and target rows (Reacher3's and Reacher4's
    widths) as two noisy nonlinear views of one 3-d hidden variable, what pairing gives a
    model to find (the shared subspace)."""
    rng = np.random.default_rng(seed)
    hidden = rng.normal(size=(rows, 3))
    width_s, width_t = sum(SOURCE_DIMS), sum(TARGET_DIMS)
    x_s = np.tanh(hidden @ rng.normal(size=(3, width_s))) + 0.05 * rng.normal(size=(rows, width_s))
    x_t = np.tanh(hidden @ rng.normal(size=(3, width_t))) + 0.05 * rng.normal(size=(rows, width_t))
    return x_s, x_t


def fit_digest() -> str:
    """Digest of a short PVED fit on :func:`paired_rows`."""
    x_s, x_t = paired_rows()
    model = train_model(
        "pved", x_s, x_t, MODEL, state_dims=(SOURCE_DIMS[0], TARGET_DIMS[0]), progress=False
    )
    with single_thread():
        losses = evaluate_model(model, x_s, x_t)
    return state_digest({"model": model.state_dict(), "losses": dict(sorted(losses.items()))})


def _bank(episodes: int = 6, length: int = 100, seed: int = 1) -> SourceBank:
    """A generated source bank matched on Reacher4 Push's button start: random walks of
    Reacher3-wide rows."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.05, size=(episodes, length, sum(SOURCE_DIMS)))
    return SourceBank(
        x=np.cumsum(steps, axis=1),
        lengths=np.full(episodes, length, dtype=np.int64),
        keys=rng.uniform(-0.2, 0.2, size=(episodes, 2)),
        header={"match_keys": ["button_start"], "robot_state_indices": list(range(11))},
    )


def shaped_digest() -> str:
    """Digest of a short PPO run on Reacher4 Push under Eq. 10's term."""
    config = PPOConfig(**{**PPO.to_dict(), "total_steps": 1024, "seed": 1})
    env = make_batched(SHAPED_ENV, config.num_envs)
    bank = _bank()
    dims = ModelDims(sum(SOURCE_DIMS), sum(TARGET_DIMS), SOURCE_DIMS[0], TARGET_DIMS[0])
    torch.manual_seed(0)
    model = PVED(dims, MODEL)
    x_s, x_t = paired_rows(256, seed=2)
    model.fit_standardization(torch.as_tensor(x_s), torch.as_tensor(x_t))
    shaping = LatentShaping(model, bank, beta=0.1, robot_state_indices=env.robot_state_indices)
    shaped = ShapedBatchedEnv(env, shaping, ("button_start",))
    with single_thread():
        policy = train_ppo(shaped, config, progress=False)
    return _policy_digest(policy, SHAPED_ENV)


#: the stages in the order they run, each a function giving its digest
STAGES: dict[str, Callable[[], str]] = {
    "ppo": ppo_digest,
    "pved-fit": fit_digest,
    "shaped": shaped_digest,
}


def compute_fingerprint() -> dict[str, str]:
    """Each stage's digest, computed now (a few seconds on one core)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with single_thread():
            return {name: stage() for name, stage in STAGES.items()}
    finally:
        torch.set_num_threads(previous)


def platform_record() -> dict[str, Any]:
    """What the digests may depend on besides the code: the numeric stack and the kernels
    torch, OpenBLAS, MKL and numpy run here."""
    return {
        **numeric_stack(),
        "blas_kernel": loaded_kernel(),
        "mkl_branch": loaded_mkl_branch(),
        "numpy_simd": loaded_numpy_simd(),
    }


def check_fingerprint(digests: dict[str, str] | None = None) -> dict[str, Any]:
    """The digests computed now (or ``digests``) against the pins: ``{"digests", "id",
    "pinned": {"digests", "id", "pinned_under"}, "changed": [stage...], "matches",
    "platform"}``. PvedError (one line) when the pin file cannot be read."""
    pins = read_pins(FINGERPRINT_PINS)
    now = compute_fingerprint() if digests is None else dict(digests)
    pinned = {k: str(v) for k, v in pins["digests"].items()}
    changed = [s for s in sorted(set(now) | set(pinned)) if now.get(s) != pinned.get(s)]
    return {
        "digests": now,
        "id": fingerprint_id(now),
        "pinned": {
            "digests": pinned,
            "id": fingerprint_id(pinned),
            "pinned_under": pins.get("pinned_under"),
        },
        "changed": changed,
        "matches": not changed,
        "platform": platform_record(),
    }


def mismatch_message(check: dict[str, Any]) -> str:
    """Why the fingerprint test fails: which stages changed, and what the commit must do."""
    changed = ", ".join(check["changed"])
    under = check["pinned"].get("pinned_under") or {}
    differs = {k: (under.get(k), v) for k, v in check["platform"].items() if under.get(k) != v}
    where = "; ".join(f"{k}: pinned under {a}, here {b}" for k, (a, b) in differs.items())
    return (
        f"the numeric fingerprint changed in stage(s) {changed} (id {check['pinned']['id']} "
        f"-> {check['id']}): this code computes other numbers than the records made under "
        f"{check['pinned']['id']}. If that is meant, update src/pved/fingerprint_pins.json "
        "on purpose (`pved fingerprint --pin`) in the commit that changes the numbers, and "
        "name in its message the records (protocol runs, docs/protocol summaries) it "
        "invalidates; if not, the change moved numerics it should not have"
        + (f" (the platform differs too: {where})" if where else "")
    )


def write_pins(digests: dict[str, str]) -> dict[str, Any]:
    """Pin ``digests`` (with the platform they were computed on) in the pin file,
    atomically; returns what was written."""
    from pved.runs import atomic_write_json

    pins = {"digests": dict(digests), "pinned_under": platform_record()}
    atomic_write_json(FINGERPRINT_PINS, pins)
    return pins
