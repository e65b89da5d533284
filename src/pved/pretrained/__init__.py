"""Small policy weights shipped with the package, reproducible with ``pved train-policy``.

Files are ``<agent>_<task>_seed<k>.pt`` (a :mod:`pved.rl.policy` file, loadable with
``weights_only=True``) beside a ``.json`` with how it was trained and evaluated.
"""

from __future__ import annotations

from pathlib import Path

from pved.errors import PvedError

PRETRAINED_DIR = Path(__file__).resolve().parent


def pretrained_policy_path(agent: str, task: str, seed: int = 0) -> Path:
    """The shipped policy of ``agent`` on ``task``; :class:`PvedError` when none is shipped."""
    path = PRETRAINED_DIR / f"{agent.lower()}_{task.lower()}_seed{seed}.pt"
    if not path.exists():
        shipped = sorted(p.stem for p in PRETRAINED_DIR.glob("*.pt"))
        raise PvedError(
            f"no pretrained policy for {agent} on {task} (seed {seed}); shipped: "
            f"{', '.join(shipped) or 'none'}"
        )
    return path
