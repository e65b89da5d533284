"""pved: skill transfer between morphologically different agents (PVED, Hu & Montana).

Importing the package registers its Gymnasium environments (``pved/<Agent><Task>-v0``).
"""

from __future__ import annotations

__version__ = "0.1.0"

# Before anything loads numpy or torch: one OpenBLAS kernel and one MKL branch on every
# machine (pved.blas).
from pved.blas import pin_portable_kernels

pin_portable_kernels()

# Registers the Gymnasium ids; the simulator modules themselves load on first use.
import pved.envs  # noqa: E402, F401
