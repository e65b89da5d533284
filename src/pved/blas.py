"""One OpenBLAS kernel on every machine, so that a stage remade elsewhere computes as before.

OpenBLAS, numpy's BLAS, picks a kernel by CPU when it loads: ``SkylakeX`` where there
is AVX-512, ``Haswell`` where there is AVX2. The kernels round matrix products
differently, and PPO's and the models' numpy backends and every policy's forward pass
are matrix products, so a bank or model remade on another machine used to differ from
the first, and the transfer runs on it by metres (docs/decisions.md, "pved pins
OpenBLAS's kernel"; torch's own kernels are not pinned). Importing :mod:`pved` sets
``OPENBLAS_CORETYPE=Haswell`` where the CPU runs that kernel and the caller has not set
one; it takes effect in every process that loads numpy after it (pved's CLI, its
scripts, the protocol's workers: :data:`pved.experiments.runner.WORKER_ENV`), and in
none that loaded numpy before.

This module must not import numpy at import time: :mod:`pved`'s ``__init__`` calls
:func:`pin_portable_kernel` before anything loads OpenBLAS.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The kernel pinned: Haswell's runs on every x86-64 CPU with AVX2 and FMA.
PORTABLE_KERNEL = "Haswell"


def kernel_env() -> dict[str, str]:
    """``OPENBLAS_CORETYPE`` for pved's processes: the caller's own where set, else
    :data:`PORTABLE_KERNEL` on a Linux x86-64 CPU with AVX2 and FMA, else nothing
    (OpenBLAS's own choice: a forced kernel the CPU lacks dies of an illegal instruction).
    """
    if os.environ.get("OPENBLAS_CORETYPE"):
        return {"OPENBLAS_CORETYPE": os.environ["OPENBLAS_CORETYPE"]}
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    lines = cpuinfo.splitlines()
    flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    if {"avx2", "fma"} <= set(flags):
        return {"OPENBLAS_CORETYPE": PORTABLE_KERNEL}
    return {}


def pin_portable_kernel() -> None:
    """Set :func:`kernel_env` in ``os.environ``, for OpenBLAS loaded after this call in
    this process and in every process started from it."""
    os.environ.update(kernel_env())


def loaded_kernel() -> str | None:
    """The kernel numpy's OpenBLAS runs in this process (``Haswell``, ``SkylakeX``, ...),
    or None where numpy's BLAS is not OpenBLAS. Each run's ``config.json`` records it."""
    import numpy  # noqa: F401  (the BLAS is found among the loaded libraries)
    from threadpoolctl import threadpool_info

    for library in threadpool_info():
        if library.get("internal_api") == "openblas":
            return library.get("architecture")
    return None
