"""pved: skill transfer between morphologically different agents (PVED, Hu & Montana).

Importing the package registers its Gymnasium environments (``pved/<Agent><Task>-v0``).
"""

from __future__ import annotations

__version__ = "0.1.0"

# Registers the Gymnasium ids; the simulator modules themselves load on first use.
import pved.envs  # noqa: F401
