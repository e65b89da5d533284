"""What one pass of ``pved-align``'s guide costs: its loss and gradient on one PPO
minibatch, in numpy (:mod:`pved.models.numpy_distance`) and by autograd, per pair.

Per pair, in one process: the pair's untrained PVED and a 16-episode bank of the shipped
source policy (as ``transfer_throughput.py`` builds them), contexts at a reset of the
target env, mean actions drawn in the box; each backend's ``loss_grad`` called
``--calls`` times on the same minibatch, the two alternated ``--repeats`` times; the
medians in µs of this process's CPU time, and numpy/autograd. Also prints the largest
difference between the two gradients, relative to the largest entry.

    .venv/bin/python benchmarks/guide_pass.py [--calls 2000] [--repeats 3] [--pairs reacher ...]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import pved  # noqa: E402, F401, I001

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from transfer_throughput import shaping_for, source_bank  # noqa: E402

from pved.envs import env_id, make_batched  # noqa: E402
from pved.spec import PRESETS, get_preset  # noqa: E402
from pved.transfer.align_guide import AlignGuide  # noqa: E402
from pved.transfer.shaping import ShapedBatchedEnv  # noqa: E402


def per_call_us(call: Callable[[], object], calls: int) -> float:
    t0 = time.process_time()
    for _ in range(calls):
        call()
    return (time.process_time() - t0) / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="calls per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="measurements per backend")
    parser.add_argument("--pairs", nargs="+", default=sorted(PRESETS), metavar="PAIR")
    args = parser.parse_args()
    if args.calls < 1 or args.repeats < 1:
        parser.error("--calls and --repeats must be >= 1")
    torch.set_num_threads(1)
    print(f"{'pair':14s} {'rows':>5s} {'numpy us':>9s} {'torch us':>9s} {'numpy/torch':>12s} "
          f"{'max grad diff':>14s}")  # fmt: skip
    for pair in args.pairs:
        preset = get_preset(pair)
        rows = preset.transfer.ppo.minibatch_size
        inner = make_batched(env_id(preset.target_agent, preset.target_task), 16)
        bank = source_bank(pair)
        shaping = shaping_for(pair, inner, bank, "align")
        env = ShapedBatchedEnv(inner, shaping, preset.bank_match_keys)
        guide = env.action_guide
        assert isinstance(guide, AlignGuide) and guide.backend == "numpy"
        obs, _ = env.reset(seed=0)
        obs = np.resize(obs, (rows, obs.shape[1]))
        rng = np.random.default_rng(0)
        context = guide.context(obs, rng.integers(0, len(bank.x), rows), np.zeros(rows, int))
        space = inner.single_action_space
        mean = rng.uniform(space.low, space.high, (rows, space.shape[0])).astype(np.float32)
        w = guide.weight(0.0)
        backends = {
            "numpy": partial(guide._loss_grad_numpy, context, mean, w),
            "torch": partial(guide._loss_grad_torch, context, mean, w),
        }
        times: dict[str, list[float]] = {name: [] for name in backends}
        for _ in range(args.repeats):
            for name, call in backends.items():
                times[name].append(per_call_us(call, args.calls))
        numpy_us, torch_us = (statistics.median(times[n]) for n in ("numpy", "torch"))
        g_np, g_t = backends["numpy"]()[1], backends["torch"]()[1]
        diff = float(np.abs(g_np - g_t).max() / max(float(np.abs(g_t).max()), 1e-30))
        print(f"{pair:14s} {rows:5d} {numpy_us:9.0f} {torch_us:9.0f} "
              f"{numpy_us / torch_us:12.2f} {diff:14.1e}")  # fmt: skip


if __name__ == "__main__":
    main()
