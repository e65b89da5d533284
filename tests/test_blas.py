"""pved.blas: which OpenBLAS kernel and MKL branch pved's processes are given."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from pved import blas


def test_portable_paths_are_pinned_on_a_cpu_that_runs_them(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENBLAS_CORETYPE", raising=False)
    monkeypatch.delenv("MKL_CBWR", raising=False)
    monkeypatch.delenv("NPY_DISABLE_CPU_FEATURES", raising=False)
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    assert blas.kernel_env() == {
        "OPENBLAS_CORETYPE": "Haswell",
        "MKL_CBWR": "COMPATIBLE",
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    }
    # a CPU without AVX2 and FMA would die of an illegal instruction: nothing is forced
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: False)
    assert blas.kernel_env() == {}


def test_the_callers_own_choice_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    monkeypatch.setenv("MKL_CBWR", "AVX512")
    monkeypatch.setenv("NPY_DISABLE_CPU_FEATURES", "AVX512_SPR")
    assert blas.kernel_env() == {
        "OPENBLAS_CORETYPE": "SkylakeX",
        "MKL_CBWR": "AVX512",
        "NPY_DISABLE_CPU_FEATURES": "AVX512_SPR",
    }
    monkeypatch.delenv("MKL_CBWR")
    monkeypatch.delenv("NPY_DISABLE_CPU_FEATURES")
    assert blas.kernel_env() == {
        "OPENBLAS_CORETYPE": "SkylakeX",
        "MKL_CBWR": "COMPATIBLE",
        "NPY_DISABLE_CPU_FEATURES": blas.PORTABLE_NUMPY_OFF,
    }


def test_a_benchmark_can_give_mkl_its_own_branch_back_but_not_the_callers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    monkeypatch.setattr(blas, "_PINNED_HERE", set())
    monkeypatch.delenv("MKL_CBWR", raising=False)
    blas.pin_portable_kernels()
    assert os.environ["MKL_CBWR"] == "COMPATIBLE"
    blas.unpin_mkl_branch()
    assert "MKL_CBWR" not in os.environ
    monkeypatch.setenv("MKL_CBWR", "AVX512")  # the caller's choice stays
    blas.pin_portable_kernels()
    blas.unpin_mkl_branch()
    assert os.environ["MKL_CBWR"] == "AVX512"


def test_mkl_runs_the_pinned_branch_on_this_cpu() -> None:
    # MKL takes a CPU branch such as AVX2 only on Intel's CPUs; on an AMD EPYC it ran its
    # own (AUTO), and a policy's initial weights differed in their last digits from an
    # Intel machine's. The pinned branch must be one this CPU's MKL runs.
    if not blas.kernel_env():
        pytest.skip("this CPU cannot run the portable paths, so nothing is pinned")
    env = {k: v for k, v in os.environ.items() if k not in ("MKL_CBWR", "OPENBLAS_CORETYPE")}
    probe = "import pved; from pved.blas import loaded_mkl_branch; print(loaded_mkl_branch())"
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == blas.PORTABLE_MKL_BRANCH


def test_numpy_runs_its_avx2_group_under_the_pin() -> None:
    # numpy's AVX-512 exp and log round otherwise than its AVX2 ones: on an AVX-512 Xeon
    # humanoid-ant's pairing dataset and models came out otherwise under each. A process
    # that imports pved before numpy must run the AVX2 group.
    if not blas.kernel_env():
        pytest.skip("this CPU cannot run the portable paths, so nothing is pinned")
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    probe = (
        "import pved, numpy; from pved.blas import loaded_numpy_simd; print(loaded_numpy_simd())"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "X86_V3"
