"""PPO training throughput: pved vs Stable-Baselines3 on Gymnasium's Hopper-v5.

Both libraries train with identical settings: 16 envs x 128 steps per update, 10 epochs,
minibatch 64, separate actor and critic of 64-64 tanh with orthogonal init, lr 3e-4
(constant), gamma 0.99, GAE lambda 0.95, clip 0.2, no value clipping, entropy 0, value
weight 0.5 on SB3's plain MSE (= pved's vf_coef 1.0 on its 1/2-MSE), grad-norm 0.5,
Adam eps 1e-5, per-minibatch advantage standardisation, no observation or reward
normalisation, actions clipped to the bounds, truncated episodes bootstrapped; one torch
thread each, the same number of env steps. SB3 steps a ``DummyVecEnv`` of 16
``gym.make("Hopper-v5")``; pved steps ``HopperV5Batch`` (the same hopper.xml, checked
transition-for-transition against Gymnasium in tests/test_ppo.py) and, for reference,
``GymnasiumBatch`` over 16 ``gym.make("Hopper-v5")``.

Also printed: raw MuJoCo throughput of the same model (an ``mj_step(nstep=4)`` loop over
16 MjData, the ceiling for any learner) and pved with its own Hopper learning config
(benchmarks/ppo_learning.py). The last line is ``ratio pved/sb3: X.XX``.

    .venv/bin/python benchmarks/ppo_throughput.py [--steps 65536]
"""

from __future__ import annotations

import os

# one BLAS/OpenMP thread, set before numpy/torch load their libraries
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ppo_learning import hopper_learning_config  # noqa: E402
from pved.blas import loaded_kernel, loaded_mkl_branch, unpin_mkl_branch  # noqa: E402
from pved.envs.gym_adapter import GymnasiumBatch  # noqa: E402
from pved.envs.hopper_v5 import FRAME_SKIP, HopperV5Batch, gymnasium_hopper_xml  # noqa: E402
from pved.rl.ppo import PPOConfig, train_ppo  # noqa: E402

# pved pins MKL's COMPATIBLE branch on import (pved.blas); the torch peer runs on the machine's
# own branch, as it would without pved (unless the caller set MKL_CBWR)
unpin_mkl_branch()

NUM_ENVS = 16
N_STEPS = 128
EPOCHS = 10
MINIBATCH = 64


def matched_config(total_steps: int, seed: int) -> PPOConfig:
    """pved's PPOConfig equal to SB3's PPO defaults at 16 x 128 / minibatch 64."""
    return PPOConfig(
        total_steps=total_steps,
        num_envs=NUM_ENVS,
        steps_per_env=N_STEPS,
        epochs=EPOCHS,
        minibatch_size=MINIBATCH,
        lr=3e-4,
        anneal_lr=False,
        adam_eps=1e-5,
        gamma=0.99,
        gae_lambda=0.95,
        clip=0.2,
        clip_value=None,
        ent_coef=0.0,
        vf_coef=1.0,  # SB3: 0.5 * mean((V-R)^2); pved: vf_coef * 0.5 * mean((V-R)^2)
        max_grad_norm=0.5,
        target_kl=None,
        normalize_advantage=True,
        hidden_sizes=(64, 64),
        activation="tanh",
        init_log_std=0.0,
        normalize_obs=False,
        normalize_reward=False,
        seed=seed,
        checkpoint_every=0,
    )


def raw_mujoco_rate(steps: int) -> float:
    """Env steps/s of a bare mj_step(nstep=4) loop over 16 MjData of hopper.xml."""
    model = mujoco.MjModel.from_xml_path(str(gymnasium_hopper_xml()))
    datas = [mujoco.MjData(model) for _ in range(NUM_ENVS)]
    rng = np.random.default_rng(0)
    ctrl = rng.uniform(-0.1, 0.1, size=(NUM_ENVS, model.nu))
    rounds = max(1, steps // NUM_ENVS)
    t0 = time.perf_counter()
    for _ in range(rounds):
        for d, c in zip(datas, ctrl, strict=True):
            d.ctrl[:] = c
            mujoco.mj_step(model, d, nstep=FRAME_SKIP)
    return rounds * NUM_ENVS / (time.perf_counter() - t0)


def gym_step_rate(steps: int) -> float:
    """Steps/s of one gym.make("Hopper-v5") stepped from Python with random actions."""
    env = gym.make("Hopper-v5")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(steps, 3)).astype(np.float32)
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


def sb3_rate(total_steps: int, seed: int) -> float:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    venv = make_vec_env("Hopper-v5", n_envs=NUM_ENVS, seed=seed, vec_env_cls=DummyVecEnv)
    model = PPO(
        "MlpPolicy",  # default: separate pi/vf 64-64 tanh, orthogonal init, log_std 0
        venv,
        learning_rate=3e-4,
        n_steps=N_STEPS,
        batch_size=MINIBATCH,
        n_epochs=EPOCHS,
        gamma=0.99,
        gae_lambda=0.95,
        clip_range=0.2,
        clip_range_vf=None,
        normalize_advantage=True,
        ent_coef=0.0,
        vf_coef=0.5,
        max_grad_norm=0.5,
        target_kl=None,
        seed=seed,
        device="cpu",
        verbose=0,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=total_steps, progress_bar=False)
    rate = model.num_timesteps / (time.perf_counter() - t0)
    venv.close()
    return rate


def pved_rate(env_factory: str, config: PPOConfig) -> float:
    env = (
        HopperV5Batch(NUM_ENVS)
        if env_factory == "replica"
        else GymnasiumBatch(env_id="Hopper-v5", num_envs=NUM_ENVS)
    )
    t0 = time.perf_counter()
    train_ppo(env, config, progress=False)
    return config.num_updates * config.batch_size / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=65536, help="env steps per learner")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-adapter", action="store_true", help="skip pved+GymnasiumBatch")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"OpenBLAS kernel {loaded_kernel()}, MKL branch {loaded_mkl_branch()}", flush=True)
    warnings.filterwarnings("ignore")

    steps = args.steps
    print(
        f"Hopper-v5, {NUM_ENVS} envs x {N_STEPS} steps/update, {EPOCHS} epochs, minibatch "
        f"{MINIBATCH}, 64-64 tanh, {steps} env steps per learner, torch threads 1",
        flush=True,
    )
    print(
        f"raw MuJoCo mj_step(nstep={FRAME_SKIP}) loop over {NUM_ENVS} MjData: "
        f"{raw_mujoco_rate(20000):9.0f} env-steps/s",
        flush=True,
    )
    print(
        f"gym.make('Hopper-v5').step from Python:            {gym_step_rate(10000):9.0f} steps/s",
        flush=True,
    )
    matched = matched_config(steps, args.seed)
    pved = pved_rate("replica", matched)
    print(
        f"pved PPO, HopperV5Batch (SB3-matched settings):     {pved:9.0f} env-steps/s", flush=True
    )
    if not args.skip_adapter:
        adapter = pved_rate("adapter", matched)
        print(
            f"pved PPO, GymnasiumBatch of 16 gym envs:           {adapter:9.0f} env-steps/s",
            flush=True,
        )
    own = hopper_learning_config(steps, args.seed)
    own_rate = pved_rate("replica", own)
    print(
        f"pved PPO, HopperV5Batch, ppo_learning.py config:   {own_rate:9.0f} env-steps/s "
        f"({'-'.join(map(str, own.hidden_sizes))} {own.activation}, "
        f"minibatch {own.minibatch_size}, obs+reward normalisation)",
        flush=True,
    )
    sb3 = sb3_rate(steps, args.seed)
    print(f"SB3 PPO, DummyVecEnv of 16 gym envs:               {sb3:9.0f} env-steps/s", flush=True)
    print(f"ratio pved/sb3: {pved / sb3:.2f}")


if __name__ == "__main__":
    main()
