"""Test-wide settings that must hold before MuJoCo and numpy are imported."""

from __future__ import annotations

import os

# Offscreen rendering on machines without a display (CI, `pytest` run by hand); `make test`
# exports the same default.
os.environ.setdefault("MUJOCO_GL", "osmesa")

# pved pins OpenBLAS's kernel when imported (pved.blas), which holds only if numpy loads
# after it: the tests then compute as pved's CLI and the protocol's workers do.
import pved  # noqa: F401
