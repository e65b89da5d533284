"""pved.blas: which OpenBLAS kernel and MKL branch pved's processes are given."""

from __future__ import annotations

import os

import pytest

from pved import blas


def test_portable_paths_are_pinned_on_a_cpu_that_runs_them(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENBLAS_CORETYPE", raising=False)
    monkeypatch.delenv("MKL_CBWR", raising=False)
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    assert blas.kernel_env() == {"OPENBLAS_CORETYPE": "Haswell", "MKL_CBWR": "AVX2"}
    # a CPU without AVX2 and FMA would die of an illegal instruction: nothing is forced
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: False)
    assert blas.kernel_env() == {}


def test_the_callers_own_choice_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    monkeypatch.setenv("MKL_CBWR", "COMPATIBLE")
    assert blas.kernel_env() == {"OPENBLAS_CORETYPE": "SkylakeX", "MKL_CBWR": "COMPATIBLE"}
    monkeypatch.delenv("MKL_CBWR")
    assert blas.kernel_env() == {"OPENBLAS_CORETYPE": "SkylakeX", "MKL_CBWR": "AVX2"}


def test_a_benchmark_can_give_mkl_its_own_branch_back_but_not_the_callers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(blas, "_cpu_runs_portable_paths", lambda: True)
    monkeypatch.setattr(blas, "_PINNED_HERE", set())
    monkeypatch.delenv("MKL_CBWR", raising=False)
    blas.pin_portable_kernels()
    assert os.environ["MKL_CBWR"] == "AVX2"
    blas.unpin_mkl_branch()
    assert "MKL_CBWR" not in os.environ
    monkeypatch.setenv("MKL_CBWR", "AVX512")  # the caller's choice stays
    blas.pin_portable_kernels()
    blas.unpin_mkl_branch()
    assert os.environ["MKL_CBWR"] == "AVX512"
