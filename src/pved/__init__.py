"""pved: skill transfer between morphologically different agents (PVED, Hu & Montana).

Importing the package registers its Gymnasium environments (``pved/<Agent><Task>-v0``).
"""

from __future__ import annotations

__version__ = "0.1.0"

# Before anything loads numpy or torch: one OpenBLAS kernel and one MKL branch on every
# machine (pved.blas).
from pved.blas import pin_portable_kernels

pin_portable_kernels()

# Registers the Gymnasium ids from the catalogue alone: neither pved.envs nor the
# simulator load until an env is made, so `import pved.models` stays free of them.
from pved.env_ids import register_envs  # noqa: E402

register_envs()
