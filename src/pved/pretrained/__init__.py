"""Small policy weights shipped with the package, reproducible with ``pved train-policy``.

Files are ``<agent>_<task>_seed<k>.pt`` (a :mod:`pved.rl.policy` file, loadable with
``weights_only=True``) beside a ``.json`` with how it was trained and evaluated.
"""

from __future__ import annotations

from pathlib import Path

from pved.errors import PvedError

PRETRAINED_DIR = Path(__file__).resolve().parent


def _stem(agent: str, task: str) -> str:
    return f"{agent.lower()}_{task.lower()}_seed"


def shipped_seeds(agent: str, task: str) -> list[int]:
    """The seeds of ``agent``'s shipped policies on ``task``, ascending.

    Not always 0, 1, 2: a seed whose policy fell short of its issue's bar is not shipped
    (docs/results.md lists those), so the k-th policy of a task is the k-th of these."""
    stem = _stem(agent, task)
    seeds = (p.stem.removeprefix(stem) for p in PRETRAINED_DIR.glob(f"{stem}*.pt"))
    return sorted(int(s) for s in seeds if s.isdigit())


def pretrained_policy_path(agent: str, task: str, seed: int | None = None) -> Path:
    """The shipped policy of ``agent`` on ``task`` with ``seed`` (default: the lowest
    shipped seed); :class:`PvedError` when none is shipped."""
    if seed is None:
        seeds = shipped_seeds(agent, task)
        seed = seeds[0] if seeds else 0
    path = PRETRAINED_DIR / f"{_stem(agent, task)}{seed}.pt"
    if not path.exists():
        shipped = sorted(p.stem for p in PRETRAINED_DIR.glob("*.pt"))
        raise PvedError(
            f"no pretrained policy for {agent} on {task} (seed {seed}); shipped: "
            f"{', '.join(shipped) or 'none'}"
        )
    return path
