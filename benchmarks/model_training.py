"""PVED training speed: the numpy backend against torch autograd, in the same run.

Both backends train the same model (``pved``, or ``--model``; Table 1's α, batch 256,
lr 1e-4, one thread) from the same initialisation on the same paired rows, at the
Walker2d-Hopper pair's widths (x_S = 17 state + 6 action, x_T = 11 + 3); their epochs are timed in
alternation so that a busy machine slows both alike. Printed: milliseconds per training
step of each and the last line ``ratio torch/numpy: X.XX`` (>1: numpy is faster). It also
prints each backend's validation objective after the same steps, which should agree to
within seed-level noise (the two differ only in floating-point rounding).

    .venv/bin/python benchmarks/model_training.py [--rows 50000] [--rounds 3]
"""

from __future__ import annotations

import os

# one BLAS/OpenMP thread, set before numpy/torch load their libraries
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pved.blas import loaded_kernel, loaded_mkl_branch, unpin_mkl_branch  # noqa: E402
from pved.models import evaluate_model, train_model  # noqa: E402
from pved.runs import Run  # noqa: E402
from pved.spec import get_preset  # noqa: E402

# pved pins MKL's COMPATIBLE branch on import (pved.blas); the torch peer runs on the machine's
# own branch, as it would without pved (unless the caller set MKL_CBWR)
unpin_mkl_branch()

SOURCE_STATE, SOURCE_ACTION = 17, 6  # Walker2d
TARGET_STATE, TARGET_ACTION = 11, 3  # Hopper


def paired_rows(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of both agents driven by one 6-d phase variable, plus noise: enough structure
    for the shared subspace to be used, as on the real pair."""
    rng = np.random.default_rng(seed)
    phase = rng.normal(size=(n, 6))
    mix_s = rng.normal(size=(6, SOURCE_STATE + SOURCE_ACTION))
    mix_t = rng.normal(size=(6, TARGET_STATE + TARGET_ACTION))
    x_s = np.tanh(phase @ mix_s) + 0.05 * rng.normal(size=(n, mix_s.shape[1]))
    x_t = np.sin(phase @ mix_t) + 0.05 * rng.normal(size=(n, mix_t.shape[1]))
    return x_s.astype(np.float32), x_t.astype(np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=50_000, help="paired rows (90%% train)")
    parser.add_argument("--rounds", type=int, default=3, help="epochs per backend")
    parser.add_argument("--model", default="pved", help="pved, a pved-* variant, gupta2017")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"OpenBLAS kernel {loaded_kernel()}, MKL branch {loaded_mkl_branch()}", flush=True)
    x_s, x_t = paired_rows(args.rows, seed=0)
    cfg = get_preset("walker-hopper").model_config(args.model, seed=0)
    dims = (SOURCE_STATE, TARGET_STATE)
    seconds = {"torch": 0.0, "numpy": 0.0}
    steps = {"torch": 0, "numpy": 0}
    with tempfile.TemporaryDirectory() as tmp:
        runs = {b: Run(Path(tmp) / b, {"backend": b}, tensorboard=False) for b in seconds}
        for epoch in range(1, args.rounds + 1):
            for backend in ("torch", "numpy") if epoch % 2 else ("numpy", "torch"):
                # one more epoch in the backend's run directory: it resumes from the last
                cfg_now = dataclasses.replace(cfg, epochs=epoch, checkpoint_every=1)
                started = time.perf_counter()
                model = train_model(
                    args.model,
                    x_s,
                    x_t,
                    cfg_now,
                    runs[backend],
                    state_dims=dims,
                    progress=False,
                    backend=backend,
                )
                record = runs[backend].read_metrics()[-1]
                seconds[backend] += float(record["epoch_seconds"])
                steps[backend] = int(record["step"])
                elapsed = time.perf_counter() - started
                total = evaluate_model(model, x_s[:5000], x_t[:5000])["total"]
                print(
                    f"epoch {epoch} {backend:>5}: {record['epoch_seconds']:.1f} s (training and "
                    f"validation; {elapsed:.1f} s with the resume), objective "
                    f"{total:.3f}",
                    flush=True,
                )
    ms = {b: 1e3 * seconds[b] / steps[b] for b in seconds}
    for backend in ("torch", "numpy"):
        print(
            f"{backend:>5}: {ms[backend]:.2f} ms per step, validation included "
            f"({steps[backend]} steps)"
        )
    print(f"ratio torch/numpy: {ms['torch'] / ms['numpy']:.2f}")


if __name__ == "__main__":
    main()
