"""Rewrite the absolute paths in the records under ``docs/`` into the relative form the
writers now give them (:mod:`pved.record_paths`; docs/decisions/at-scale.md, "Paths in
records are relative"). Run from the repository root; a second run changes nothing.

    .venv/bin/python scripts/relative_record_paths.py [--check]

Each path is replaced where it stands in the file's text, so every number and every byte
around a path stays as it was; a JSON file is checked to differ from the old one in the
content of its strings only. The forms the records carried, and what each becomes:

- ``<checkout>/reports/<name>/<rest>`` in a protocol's own record
  (``docs/protocol/<name>/*.json``, ``summary.md``): ``<rest>``, relative to the protocol
  directory; anywhere else, or another protocol's: ``reports/<name>/<rest>``, relative to
  the repository;
- ``<checkout>/src/pved/<rest>`` (a shipped policy): ``src/pved/<rest>``;
- ``<somewhere>/demo-rerun/runs/<rest>`` (the demo's record, made in a scratch directory):
  ``runs/demo/<rest>``, where ``make demo`` puts those runs;
- scratch directories named in the journal: ``/root/pved-runs`` as ``~/pved-runs`` (the
  home directory of the sessions that used it), ``/tmp/<rest>`` as ``$TMPDIR/<rest>``.

A path of any other form is listed and the script fails, changing nothing.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

DOCS = Path("docs")
TEXT = ("*.md", "*.json", "*.jsonl", "*.toml", "*.csv", "*.txt", "*.html", "*.svg", "*.yml")
#: an absolute path of two parts or more where a path starts (tests/test_record_paths.py)
ABSOLUTE = re.compile(
    r"(?:^|(?<=[\s\"'`(\[=,]))/(?!(?:proc|sys|dev)/)[\w.+~-]+/[^\s\"'`)\],]*", re.MULTILINE
)
REPORTS = re.compile(r"/.+?/reports/([\w.+-]+)(?:/(.*))?")
PACKAGE = re.compile(r"/.+?/(src/pved/.+)")
DEMO = re.compile(r"/.+?/demo-rerun/runs/(.+)")
SCRATCH = (
    (re.compile(r"/root/pved-runs(/.*)?"), "~/pved-runs"),
    (re.compile(r"/tmp/(.+)"), "$TMPDIR/"),
)
#: a JSON string literal, for checking that a rewrite touched nothing else
STRING = re.compile(r'"(?:[^"\\]|\\.)*"')


def relative_form(path: str, record: Path) -> str | None:
    """``path``, found in ``record`` (a file under docs/), as the writers give it now."""
    parts = record.relative_to(DOCS).parts
    own = parts[0] == "protocol" and len(parts) == 3  # docs/protocol/<name>/<file>
    if m := REPORTS.fullmatch(path):
        name, rest = m.group(1), m.group(2)
        if own and name == parts[1] and rest:
            return rest
        return f"reports/{name}" + (f"/{rest}" if rest else "")
    if m := PACKAGE.fullmatch(path):
        return m.group(1)
    if m := DEMO.fullmatch(path):
        return f"runs/demo/{m.group(1)}"
    for pattern, prefix in SCRATCH:
        if m := pattern.fullmatch(path):
            return prefix + (m.group(1) or "")
    return None


def rewrite(text: str, record: Path, unknown: list[str]) -> str:
    """``text`` with each absolute path in its relative form (unmapped ones in ``unknown``)."""

    def one(match: re.Match[str]) -> str:
        new = relative_form(match.group(), record)
        if new is None:
            unknown.append(f"{record}: {match.group()}")
            return match.group()
        return new

    return ABSOLUTE.sub(one, text)


def check_json(old: str, new: str, record: Path) -> None:
    """The two texts load alike and differ inside string literals only."""
    if STRING.sub('""', old) != STRING.sub('""', new):
        raise SystemExit(f"{record}: the rewrite changed more than strings")
    json.loads(new)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; fail if needed")
    args = parser.parse_args(argv)
    if not DOCS.is_dir():
        print("run from the repository root (no docs/ here)", file=sys.stderr)
        return 2
    unknown: list[str] = []
    changed: dict[Path, str] = {}
    for record in sorted({p for pattern in TEXT for p in DOCS.rglob(pattern)}):
        old = record.read_bytes().decode()  # as it is: no newline translation
        new = rewrite(old, record, unknown)
        if new != old:
            if record.suffix == ".json":
                check_json(old, new, record)
            changed[record] = new
    if unknown:
        print("paths of no known form (nothing changed):", *unknown[:20], sep="\n  ")
        return 1
    if args.check:
        print(f"{len(changed)} records hold absolute paths", *sorted(map(str, changed)), sep="\n")
        return 1 if changed else 0
    for record, new in changed.items():
        record.write_bytes(new.encode())
    print(f"{len(changed)} records rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())
