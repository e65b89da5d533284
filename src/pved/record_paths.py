"""Paths as committed records hold them: relative, never a directory of the machine that
wrote them (docs/decisions/protocol.md, "Paths in records are relative").

A record (``summary.json``, ``selection.json``, ``protocol.json``,
``finished-transfer-runs.json``, the claims, scoreboard, comparison and analysis files)
is read on other machines and committed under ``docs/``; an absolute path in it names a
checkout that exists nowhere else. Writers pass every path through :func:`record_path`;
readers take one back with :func:`resolve_record_path`, which also reads the absolute
paths that records written before this rule carry.
"""

from __future__ import annotations

import os
from pathlib import Path


def _under(path: str, root: str) -> str | None:
    """``path`` relative to ``root`` where it lies under it (``.`` for ``root`` itself)."""
    rel = os.path.relpath(path, root)
    return None if rel == os.pardir or rel.startswith(os.pardir + os.sep) else rel


def record_path(path: Path | str, base: Path | str | None = None) -> str:
    """``path`` as a record writes it: relative to ``base`` (the directory the record
    describes, e.g. a protocol directory for its runs) where it lies under it, else
    relative to the current directory (the repository, where ``make`` and the documented
    commands run), with ``..`` where it lies outside that too. Never absolute.

    Each root is tried as written and with its links resolved, so that a ``reports/``
    that is a link to a larger disk still gives ``reports/...``."""
    roots = ([base] if base is not None else []) + [os.getcwd()]
    for root in roots:
        for form in (os.path.abspath, os.path.realpath):
            rel = _under(form(path), form(root))
            if rel is not None:
                return Path(rel).as_posix()
    return Path(os.path.relpath(os.path.realpath(path), os.path.realpath(os.getcwd()))).as_posix()


def resolve_record_path(value: str, base: Path | str) -> Path:
    """A path read from a record whose paths are relative to ``base`` (:func:`record_path`);
    an absolute one, from a record written before they were relative, as it stands."""
    return Path(base) / value
