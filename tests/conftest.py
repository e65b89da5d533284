"""Test-wide settings that must hold before MuJoCo is imported."""

from __future__ import annotations

import os

# Offscreen rendering on machines without a display (CI, `pytest` run by hand); `make test`
# exports the same default.
os.environ.setdefault("MUJOCO_GL", "osmesa")
