"""What Eq. 10's shaping costs a transfer run: env steps/s of a shaped PPO run against
plain PPO on the same target env, and of raw MuJoCo on that env's model, per pair.

Per pair, in one process and one run: (1) raw MuJoCo, the bare ``mj_step(nstep=frame_skip)``
loop over the batched target env's 16 ``MjData`` (the ceiling); (2) the target env alone,
stepped with random actions (MuJoCo plus the task's numpy logic); (3) plain PPO on it with
the pair's transfer config; (4) the same PPO on the env wrapped in Eq. 10's shaping, with a
PVED of the pair's architecture and a source bank of the shipped source policy's rollouts.
The model is untrained: the shaping's cost is the forward passes, which do not depend on
the weights. Evaluations and checkpoints are off, so (3) and (4) time training alone; (4)
includes encoding the bank's source half, once per run (``pved.transfer.source_cache``).
(3) and (4) alternate ``--repeats`` times and each reports its median rate, so a load
that comes and goes on a shared machine weighs on both alike. Rates are per second of
this process's CPU time unless ``--clock wall`` (see ``CLOCKS``).

Prints one line per pair and the ratios ``shaped/ppo`` (the goal: at least 0.85) and
``ppo/raw``. ``--forms`` measures other shaping forms (a method's, ``pved list``) beside
Eq. 10's, each in the same alternation, with a ratio of its own.

    .venv/bin/python benchmarks/transfer_throughput.py [--steps 16384] [--repeats 3]
        [--clock cpu|wall] [--pairs reacher ...] [--forms eq10 align ...]
"""

from __future__ import annotations

import os

# one BLAS/OpenMP thread, set before numpy/torch load their libraries
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

# pved first: it pins the BLAS kernels (pved.blas) only for the libraries loaded after it,
# and the runs this times compute on the pinned ones
import pved  # noqa: E402, F401, I001

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from pved.spec import PRESETS, get_preset  # noqa: E402
from pved.envs import env_id, make_batched  # noqa: E402
from pved.experiments.transfer_spec import guide_limits, set_guide_gate  # noqa: E402
from pved.envs.base import BatchedEnv  # noqa: E402
from pved.models import ModelDims, build_model  # noqa: E402
from pved.pretrained import pretrained_policy_path  # noqa: E402
from pved.rl.policy import load_policy  # noqa: E402
from pved.rl.ppo import PPOConfig, train_ppo  # noqa: E402
from pved.transfer.shaping import SHAPING_FORMS, LatentShaping, ShapedBatchedEnv  # noqa: E402
from pved.transfer.source_bank import (  # noqa: E402
    SourceBank,
    bank_time_scale,
    build_source_bank,
)

BANK_EPISODES = 16


#: What the rates are measured on: "cpu" (the default), this process's CPU time, which on
#: a machine shared with other jobs counts what the run itself cost, not the time others
#: held the core (one thread here, so on an idle core the two agree); "wall", the clock.
CLOCKS = {"cpu": time.process_time, "wall": time.perf_counter}
clock = CLOCKS["cpu"]


def raw_mujoco_rate(env: BatchedEnv, steps: int) -> float:
    """Env steps/s of a bare ``mj_step(nstep=frame_skip)`` loop over the env's MjData."""
    model, datas = env.model, env.datas  # type: ignore[attr-defined]
    nstep = int(env.frame_skip)  # type: ignore[attr-defined]
    ctrl = np.random.default_rng(0).uniform(-0.1, 0.1, size=(len(datas), model.nu))
    rounds = max(1, steps // len(datas))
    t0 = clock()
    for _ in range(rounds):
        for data, c in zip(datas, ctrl, strict=True):
            data.ctrl[:] = c
            mujoco.mj_step(model, data, nstep=nstep)
    return rounds * len(datas) / (clock() - t0)


def env_rate(env: BatchedEnv, steps: int) -> float:
    """Env steps/s of the batched env stepped with random actions."""
    env.reset(seed=0)
    space = env.single_action_space
    rng = np.random.default_rng(0)
    rounds = max(1, steps // env.num_envs)
    actions = rng.uniform(space.low, space.high, size=(rounds, env.num_envs, space.shape[0]))
    t0 = clock()
    for a in actions:
        env.step(a)
    return rounds * env.num_envs / (clock() - t0)


def ppo_rate(env: BatchedEnv, config: PPOConfig) -> float:
    t0 = clock()
    train_ppo(env, config, progress=False)
    return config.num_updates * config.batch_size / (clock() - t0)


def source_bank(pair: str) -> SourceBank:
    preset = get_preset(pair)
    env = make_batched(env_id(preset.source_agent, preset.target_task), BANK_EPISODES)
    policy = load_policy(pretrained_policy_path(preset.source_agent, preset.target_task))
    return build_source_bank(env, policy, BANK_EPISODES, preset.bank_match_keys, seed=0)


def shaping_for(
    pair: str, target: BatchedEnv, bank: SourceBank, form: str = "eq10"
) -> LatentShaping:
    """Eq. 10 with an untrained PVED of the pair's architecture (see module doc)."""
    preset = get_preset(pair)
    n_t = len(target.robot_state_indices)
    n_s = len(bank.header["robot_state_indices"])
    target_dim = n_t + int(target.single_action_space.shape[0])
    dims = ModelDims(bank.dim, target_dim, n_s, n_t)
    torch.manual_seed(0)
    model = build_model("pved", dims, preset.model_config("pved"))
    model.fit_standardization(
        torch.as_tensor(bank.x.reshape(-1, bank.dim)), torch.randn(1024, target_dim)
    )
    scale = bank_time_scale(preset.pairing.align, bank.dt, getattr(target, "dt", None))
    return LatentShaping(
        model, bank, preset.transfer.beta, target.robot_state_indices, time_scale=scale, form=form
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=16384, help="env steps per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="PPO runs of each kind")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="cpu", help="see CLOCKS")
    parser.add_argument("--pairs", nargs="+", default=sorted(PRESETS), metavar="PAIR")
    parser.add_argument("--forms", nargs="+", default=["eq10"], choices=SHAPING_FORMS)
    args = parser.parse_args()
    if args.repeats < 1 or args.steps < 1:
        parser.error("--steps and --repeats must be >= 1")
    global clock
    clock = CLOCKS[args.clock]
    torch.set_num_threads(1)
    forms = list(dict.fromkeys(args.forms))
    print(
        f"{'pair':14s} {'raw':>9s} {'env':>9s} {'ppo':>8s} "
        + " ".join(f"{f:>9s}" for f in forms)
        + "  "
        + "  ".join(f"{f + '/ppo':>10s}" for f in forms)
        + "  ppo/raw"
    )
    for pair in args.pairs:
        preset = get_preset(pair)
        target_id = env_id(preset.target_agent, preset.target_task)
        config = dataclasses.replace(
            preset.transfer.ppo, total_steps=args.steps, checkpoint_every=0, eval_every=0
        )
        bank = source_bank(pair)
        raw = raw_mujoco_rate(make_batched(target_id, config.num_envs), args.steps)
        alone = env_rate(make_batched(target_id, config.num_envs), args.steps)
        plains: list[float] = []
        shapeds: dict[str, list[float]] = {f: [] for f in forms}
        for _ in range(args.repeats):
            plains.append(ppo_rate(make_batched(target_id, config.num_envs), config))
            for form in forms:
                inner = make_batched(target_id, config.num_envs)
                shaped_env = ShapedBatchedEnv(
                    inner, shaping_for(pair, inner, bank, form), preset.bank_match_keys
                )
                if shaped_env.action_guide is not None:  # its reward gate as a run's
                    set_guide_gate(shaped_env.action_guide, guide_limits(form, preset))
                shapeds[form].append(ppo_rate(shaped_env, config))
        plain = statistics.median(plains)
        shaped = {f: statistics.median(r) for f, r in shapeds.items()}
        print(
            f"{pair:14s} {raw:9.0f} {alone:9.0f} {plain:8.0f} "
            + " ".join(f"{shaped[f]:9.0f}" for f in forms)
            + "  "
            + "  ".join(f"{shaped[f] / plain:10.2f}" for f in forms)
            + f"  {plain / raw:7.2f}"
        )


if __name__ == "__main__":
    main()
