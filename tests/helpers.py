"""Helpers shared by several test modules (pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from pved import __version__
from pved.cli import main
from pved.envs.base import BatchedEnv
from pved.protocol.plan import PLAN_FILE, ProtocolPlan
from pved.rl.policy import Policy
from pved.rl.ppo import PPOConfig, train_ppo
from pved.runs import Run, atomic_write_json


def run_cli(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """``pved ARGV...`` in this process: (exit code, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def reacher_smoke_protocol(out: Path) -> Path:
    """A reacher smoke protocol (pved, ppo) in ``out`` whose transfer runs can all start:
    its pairs, bank and seed-0 model made by the plan's own jobs, no transfer run made."""
    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", out)
    atomic_write_json(out / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    jobs = {j.key: j for j in plan.expand({})}
    for key in ("reacher/pairs", "reacher/bank/src0", "reacher/model/pved/init0"):
        jobs[key].fn(**jobs[key].kwargs)
    return out


def params_of(policy: Policy) -> np.ndarray:
    """A policy's network weights as one flat array."""
    return torch.cat([p.detach().flatten() for p in policy.net.parameters()]).numpy().copy()


class Interrupt(Exception):
    """Raised from an evaluation callback to kill a training run mid-way."""


def assert_ppo_resumes_exactly(
    make_env: Callable[[], BatchedEnv], cfg: PPOConfig, root: Path
) -> None:
    """PPO killed after its checkpoint at update 2 and resumed ends with the weights of an
    uninterrupted run (``cfg``: 5 updates, a checkpoint every 2), without the warning of
    a resume that had to start fresh episodes, and logs each update once."""
    per_update = cfg.num_envs * cfg.steps_per_env
    straight = train_ppo(make_env(), cfg, Run(root / "a", {"c": 1}), progress=False)

    def crash_at_4th_update(policy: Policy, steps: int) -> dict[str, float]:
        if steps == 4 * per_update:  # after the checkpoint at update 2, before the one at 4
            raise Interrupt
        return {}

    run_b = Run(root / "b", {"c": 1})
    with pytest.raises(Interrupt):
        train_ppo(make_env(), cfg, run_b, eval_fn=crash_at_4th_update, progress=False)
    assert run_b.latest_checkpoint()["global_step"] == 2 * per_update  # type: ignore[index]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resumed = train_ppo(make_env(), cfg, Run(root / "b", {"c": 1}), progress=False)
    assert not [w for w in caught if "freshly reset episodes" in str(w.message)]
    assert np.array_equal(params_of(straight), params_of(resumed))
    assert np.array_equal(straight.obs_normalizer.rms.mean, resumed.obs_normalizer.rms.mean)
    # the updates logged after the checkpoint by the interrupted run are not duplicated
    logged = [r["step"] for r in run_b.read_metrics() if "loss/approx_kl" in r]
    assert logged == [k * per_update for k in range(1, 6)]


def push_bank_and_model(episodes: int = 8) -> tuple[Any, Any]:
    """A source bank of the shipped Reacher3 Push policy (``episodes`` episodes, seed 5)
    and an untrained PVED for the Reacher3 → Reacher4 Push pair, its standardisation fit
    on rough data so the encoders see unit-scale inputs: the shaping tests' inputs."""
    from pved.envs import make_batched
    from pved.models import PVED, ModelDims, PVEDConfig
    from pved.pretrained import pretrained_policy_path
    from pved.rl.policy import load_policy
    from pved.transfer.source_bank import build_source_bank

    env = make_batched("pved/Reacher3Push-v0", 4)
    policy = load_policy(pretrained_policy_path("Reacher3", "Push"))
    bank = build_source_bank(env, policy, episodes, ("button_start",), seed=5)
    target = make_batched("pved/Reacher4Push-v0", 1)
    n_tgt = len(target.robot_state_indices)
    n_src = len(bank.header["robot_state_indices"])
    dims = ModelDims(bank.dim, n_tgt + target.single_action_space.shape[0], n_src, n_tgt)
    torch.manual_seed(0)
    model = PVED(dims, PVEDConfig())
    model.fit_standardization(
        torch.as_tensor(bank.x.reshape(-1, bank.dim)), torch.randn(512, dims.target_dim)
    )
    return bank, model


def placeholder_shaping_inputs(runs: Path) -> tuple[Path, Path]:
    """reacher's default model and bank files under ``runs``, with placeholder bytes: a
    transfer spec hashes them and reads nothing else. Returns (model, bank)."""
    model = runs / "reacher" / "model" / "pved" / "seed0" / "model.pt"
    bank = runs / "reacher" / "bank" / "Reacher3-Push" / "seed0" / "bank.npz"
    for path in (model, bank):
        path.parent.mkdir(parents=True)
        path.write_bytes(path.name.encode())
    return model, bank


def first_minibatch(trainer: Any, rows: int) -> tuple[np.ndarray, ...]:
    """The first ``rows`` rows of a PPO trainer's rollout buffers, after a rollout, in
    ``_grad_numpy``'s argument order (the guide's context last)."""
    adv, ret = trainer.advantages()
    n = trainer.cfg.batch_size
    return (
        trainer.buf_obs.reshape(n, -1)[:rows],
        trainer.buf_act.reshape(n, -1)[:rows],
        trainer.buf_logp.reshape(n)[:rows],
        adv.reshape(n)[:rows].astype(np.float32),
        ret.reshape(n)[:rows].astype(np.float32),
        trainer.buf_val.reshape(n)[:rows],
        trainer.buf_ctx.reshape(n, -1)[:rows],
    )


#: A pair pved has never seen: Gymnasium's stock two-link Reacher (an SB3 policy on both
#: tasks) teaches pved's three-link Reacher3. Stock envs report no task parameter, so
#: episodes pair by reset seed and a bank episode is drawn at random.
STOCK_REACHER_SPEC = """\
name = "stock-reacher"
training_task = "Reach"
target_task = "Push"

[source]
agent = "StockReacher2"
robot_state = [0, 1, 2, 3, 6, 7]   # cos, sin and velocity of both joints

[source.training]
env = "Reacher-v5"
policy = "stock_reach.zip"

[source.target]
env = "Reacher-v5"
kwargs = {{ reward_control_weight = 0.5 }}
policy = "stock_push.zip"

[target]
agent = "Reacher3"

[target.training]
env = "pved/Reacher3Reach-v0"

[target.target]
env = "pved/Reacher3Push-v0"

[tasks]
shared = []
bank_match = []

[protocol]
beta_grid = [0.1, 0.01]
steps = {{ smoke = {smoke_steps}, quick = 300000 }}
"""


def stock_reacher_spec(folder: Path, smoke_steps: int = 8192) -> Path:
    """``folder/stock-reacher.toml`` (:data:`STOCK_REACHER_SPEC`) beside its two SB3 PPO
    policies, untrained (what they do does not matter, only that pved runs them);
    ``smoke_steps``: env steps of a transfer run at the smoke budget."""
    import gymnasium as gym
    import stable_baselines3 as sb3

    folder.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    for name in ("stock_reach.zip", "stock_push.zip"):
        model = sb3.PPO(
            "MlpPolicy",
            gym.make("Reacher-v5"),
            policy_kwargs={"net_arch": [16]},
            seed=0,
            device="cpu",
        )
        model.save(folder / name)
    spec = folder / "stock-reacher.toml"
    spec.write_text(STOCK_REACHER_SPEC.format(smoke_steps=smoke_steps))
    return spec


#: Evaluation steps of :func:`protocol_dir`'s runs.
CURVE_STEPS = [0, 1000, 2000, 3000, 4000]


def protocol_dir(
    root: Path,
    pairs: dict[str, dict[str, list[list[float]]]],
    budget: str = "paper",
    **marks: Any,
) -> Path:
    """A finished protocol directory of ``budget`` whose runs have these curves at
    :data:`CURVE_STEPS` (metric ``score``; a method's final score is its curve's last
    point); ``marks``: extra fields of a method's entry on every pair (``{"new":
    {"exploratory": True}}``)."""
    import json

    root.mkdir(parents=True)
    summary: dict[str, Any] = {"budget": budget, "pairs": {}}
    for pair, methods in pairs.items():
        entries: dict[str, Any] = {}
        for method, curves in methods.items():
            runs = []
            for i, curve in enumerate(curves):
                key = f"{pair}/transfer/{method}/seed{i}"
                run_dir = root / "runs" / key
                run_dir.mkdir(parents=True)
                rows = [
                    {"step": s, "eval/score": v} for s, v in zip(CURVE_STEPS, curve, strict=True)
                ]
                (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
                runs.append({"key": key, "seed": i, "score": curve[-1]})
            entries[method] = {"runs": runs, **marks.get(method, {})}
        summary["pairs"][pair] = {"metric": "score", "methods": entries}
    (root / "summary.json").write_text(json.dumps(summary))
    return root
