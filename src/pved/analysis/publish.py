"""``pved publish``: every table of results in README.md, docs/results.md and
docs/results/<pair>.md, generated from the committed records (``docs/protocol/*/
summary.json``, the runs' finals there, and the runs' curves in each directory's
``finished-transfer-runs.json``), so that a number is typed nowhere and one method's runs
carry one interval on every page.

A page holds a table between two markers, ``<!-- pved:table NAME ARGS -->`` and
``<!-- /pved:table -->``; :func:`publish` replaces what lies between them with the table
NAME makes (:data:`pved.analysis.result_tables.TABLES`), and :func:`stale_pages` says
which pages differ from their records (``pved publish --check``, and the test that keeps
the pages true).

The tables and how their numbers are made: :mod:`pved.analysis.result_tables`.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from pved.analysis.judge import FOUR
from pved.analysis.result_tables import TABLES
from pved.analysis.result_tables import Records as Records
from pved.errors import PvedError

PAGES = ("README.md", "docs/results.md", *(f"docs/results/{p}.md" for p in FOUR))
"""The pages whose tables are generated."""
BLOCK = re.compile(
    r"(?P<open><!-- pved:table (?P<spec>[^>]*?) -->\n)(?P<body>.*?)(?P<close><!-- /pved:table -->)",
    re.DOTALL,
)

# ---------------------------------------------------------------------------- pages


def render_page(rec: Records, page: str, text: str) -> str:
    """``text`` (the page ``page``, a path from the root) with every table between its
    markers made anew. PvedError (one line) for an unknown table, wrong arguments or a
    marker left open."""

    def fill(match: re.Match[str]) -> str:
        name, *args = match["spec"].split()
        if name not in TABLES:
            raise PvedError(f"{page}: unknown table {name!r} (known: {', '.join(TABLES)})")
        try:
            body = TABLES[name](rec, page, *args)
        except TypeError as exc:
            raise PvedError(f"{page}: table {match['spec']!r}: wrong arguments ({exc})") from exc
        return f"{match['open']}\n{body}\n\n{match['close']}"

    out = BLOCK.sub(fill, text)
    if out.count("<!-- pved:table ") != out.count("<!-- /pved:table -->"):
        raise PvedError(f"{page}: a <!-- pved:table ... --> marker without its close")
    return out


def render(root: Path, pages: Sequence[str] = PAGES, rec: Records | None = None) -> dict[str, str]:
    """Each page of ``pages`` under ``root`` (that exists) as its tables make it now."""
    rec = rec if rec is not None else Records(root)
    out = {}
    for page in pages:
        path = Path(root) / page
        if path.is_file():
            out[page] = render_page(rec, page, path.read_text())
    return out


def stale_pages(root: Path, pages: Sequence[str] = PAGES) -> list[str]:
    """The pages whose tables differ from what their records make now."""
    return [
        page
        for page, text in render(root, pages).items()
        if text != (Path(root) / page).read_text()
    ]


def publish(root: Path, pages: Sequence[str] = PAGES, check: bool = False) -> list[str]:
    """Regenerate the tables of ``pages`` under ``root`` from the records; returns the
    pages that changed (with ``check``: that would change; nothing is written). Every
    page is made before any is written, each atomically."""
    made = render(root, pages)
    changed = [p for p, text in made.items() if text != (Path(root) / p).read_text()]
    if not check:
        # Imported here: pved.runs imports torch, which reading records does not need.
        from pved.runs import atomic_write_bytes

        for page in changed:
            atomic_write_bytes(Path(root) / page, made[page].encode())
    return changed


def verdict_flips(
    root: Path, reps: int, seeds: Sequence[int], pages: Sequence[str] = PAGES
) -> dict[str, dict[str, int]]:
    """Every verdict the pages print, made with ``reps`` resamples under each of
    ``seeds``: label -> {verdict: how many seeds gave it}. A label with two verdicts
    flips with the resampling's seed."""
    counts: dict[str, dict[str, int]] = {}
    for seed in seeds:
        rec = Records(root, reps=reps, seed=seed)
        render(root, pages, rec)
        for label, verdict in rec.verdicts.items():
            by = counts.setdefault(label, {})
            by[verdict] = by.get(verdict, 0) + 1
    return counts
