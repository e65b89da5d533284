"""One BLAS code path on every machine, so that a stage remade elsewhere computes as before.

Three libraries pick their code by CPU when they load, and round differently on each path:

- OpenBLAS, numpy's BLAS, picks a kernel: ``SkylakeX`` where there is AVX-512,
  ``Haswell`` where there is AVX2. PPO's and the models' numpy backends and every
  policy's forward pass are matrix products, so a bank or model remade on another
  machine used to differ from the first, and the transfer runs on it by metres
  (docs/decisions.md, "pved pins OpenBLAS's kernel").
- MKL, the LAPACK inside torch's CPU build, picks a branch; the QR decomposition behind
  the policies' orthogonal initialisation (``torch.nn.init.orthogonal_``) runs through
  it, so the same seed gave another initial policy on another machine
  (docs/decisions.md, "pved pins MKL's branch"). MKL honours a pinned CPU branch
  (``AVX2``, ``AVX512``) only on Intel's CPUs and runs its own choice (``AUTO``)
  elsewhere; ``COMPATIBLE`` it honours on every CPU, and computes the same there.
- numpy itself dispatches its elementwise functions (``exp``, ``log``, ``expm1``,
  ``log1p``, ``power``) to the widest SIMD group the CPU has, and its AVX-512 groups
  (``X86_V4`` and above) round otherwise than its AVX2 group (``X86_V3``). The Gaussian
  log-likelihoods of the models run through them, and so did the pairs' rollouts: on an
  AVX-512 Xeon, humanoid-ant's pairing dataset and models came out otherwise under each
  group (docs/decisions.md, "pved pins numpy's SIMD group").

Importing :mod:`pved` sets ``OPENBLAS_CORETYPE=Haswell``, ``MKL_CBWR=COMPATIBLE`` and
``NPY_DISABLE_CPU_FEATURES`` (numpy's groups above ``X86_V3``) where the CPU runs those
paths and the caller has not set them. Each takes effect in every process that loads its
library after the import (pved's CLI, its scripts, the protocol's workers:
:data:`pved.protocol.runner.WORKER_ENV`), and in none that loaded it before.

This module must not import numpy or torch at import time: :mod:`pved`'s ``__init__``
calls :func:`pin_portable_kernels` before anything loads OpenBLAS or MKL.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

#: OpenBLAS's kernel pinned: Haswell's runs on every x86-64 CPU with AVX2 and FMA.
PORTABLE_KERNEL = "Haswell"
#: MKL's conditional-numerical-reproducibility branch pinned, for the same CPUs: the one
#: MKL takes on AMD's CPUs as on Intel's (it ignores ``AVX2`` on an AMD EPYC and runs
#: ``AUTO``, which rounds otherwise).
PORTABLE_MKL_BRANCH = "COMPATIBLE"
#: numpy's SIMD groups switched off, for the same CPUs: every dispatch target of numpy
#: 2.4.6 above ``X86_V3`` (AVX2 and FMA), so that numpy runs its AVX2 code everywhere.
#: A group the CPU lacks is off anyway; naming it costs nothing.
PORTABLE_NUMPY_OFF = "X86_V4 AVX512_ICL AVX512_SPR"

# MKL's MKL_CBWR_* codes (mkl_service.h), as mkl_cbwr_get returns them; 1 (BRANCH_OFF)
# is no pin: MKL's own choice by CPU.
_MKL_BRANCHES = {
    1: "off",
    2: "AUTO",
    3: "COMPATIBLE",
    4: "SSE2",
    6: "SSSE3",
    7: "SSE4_1",
    8: "SSE4_2",
    9: "AVX",
    10: "AVX2",
    11: "AVX512_MIC",
    12: "AVX512",
    13: "AVX512_MIC_E1",
    14: "AVX512_E1",
}
_MKL_CBWR_BRANCH = 1  # mkl_cbwr_get's argument: the branch, not the STRICT flag


def _cpu_runs_portable_paths() -> bool:
    """Whether this is a Linux x86-64 CPU with AVX2 and FMA (a forced kernel the CPU
    lacks dies of an illegal instruction)."""
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    lines = cpuinfo.splitlines()
    flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    return {"avx2", "fma"} <= set(flags)


def kernel_env() -> dict[str, str]:
    """``OPENBLAS_CORETYPE``, ``MKL_CBWR`` and ``NPY_DISABLE_CPU_FEATURES`` for pved's
    processes: each the caller's own where set, else :data:`PORTABLE_KERNEL`,
    :data:`PORTABLE_MKL_BRANCH` and :data:`PORTABLE_NUMPY_OFF` on a CPU with AVX2 and
    FMA, else absent (the library's own choice)."""
    portable = _cpu_runs_portable_paths()
    env: dict[str, str] = {}
    for var, value in (
        ("OPENBLAS_CORETYPE", PORTABLE_KERNEL),
        ("MKL_CBWR", PORTABLE_MKL_BRANCH),
        ("NPY_DISABLE_CPU_FEATURES", PORTABLE_NUMPY_OFF),
    ):
        if os.environ.get(var):
            env[var] = os.environ[var]
        elif portable:
            env[var] = value
    return env


#: The variables :func:`pin_portable_kernels` set itself (not the caller's own).
_PINNED_HERE: set[str] = set()


def pin_portable_kernels() -> None:
    """Set :func:`kernel_env` in ``os.environ``, for OpenBLAS and MKL loaded after this
    call in this process and in every process started from it."""
    env = kernel_env()
    _PINNED_HERE.update(var for var in env if not os.environ.get(var))
    os.environ.update(env)


def unpin_mkl_branch() -> None:
    """Leave MKL its own choice by CPU again, where pved chose the branch (not the
    caller) and MKL has not run yet in this process: for a benchmark whose torch peer
    (SB3, autograd) should run as it would without pved. The default numpy paths do not
    go through MKL; a policy's initialisation does."""
    if "MKL_CBWR" in _PINNED_HERE:
        os.environ.pop("MKL_CBWR", None)
        _PINNED_HERE.discard("MKL_CBWR")


def loaded_kernel() -> str | None:
    """The kernel numpy's OpenBLAS runs in this process (``Haswell``, ``SkylakeX``, ...),
    or None where numpy's BLAS is not OpenBLAS. Each run's ``config.json`` records it."""
    import numpy  # noqa: F401  (the BLAS is found among the loaded libraries)
    from threadpoolctl import threadpool_info

    for library in threadpool_info():
        if library.get("internal_api") == "openblas":
            return library.get("architecture")
    return None


def loaded_mkl_branch() -> str | None:
    """The branch torch's MKL runs in this process (``COMPATIBLE``, ``AVX2``, ``off`` where
    none is pinned, ...), or None where torch carries no MKL that says. Each run's
    ``config.json`` records it.

    torch links MKL into ``libtorch_cpu`` and exports its service function under the
    internal name ``mkl_serv_cbwr_get``; asking it also settles the branch, from
    ``MKL_CBWR``, if MKL has not run yet."""
    import torch

    library = Path(torch.__file__).parent / "lib" / "libtorch_cpu.so"
    try:
        cbwr_get = ctypes.CDLL(str(library)).mkl_serv_cbwr_get
    except (OSError, AttributeError):
        return None
    code = int(cbwr_get(_MKL_CBWR_BRANCH))
    return _MKL_BRANCHES.get(code, str(code))


def loaded_numpy_simd() -> str | None:
    """The widest SIMD group numpy dispatches to in this process (``X86_V3`` under the
    pin, ``X86_V4`` or ``AVX512_ICL`` on an AVX-512 CPU without it), or None where numpy
    does not say (no group of its own dispatch list runs). Each run's ``config.json``
    records it."""
    # numpy's own record of its dispatch (what `numpy.show_runtime` prints); private,
    # hence the guard: a numpy without it records None rather than failing a run
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return None
    running = [group for group in __cpu_dispatch__ if __cpu_features__.get(group)]
    return running[-1] if running else None
