"""The front door: README.md stays short, starts with the two set-up commands, and links
only to files that are there (the docs site's own links are `make docs`'s to check)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_readme_is_short_and_starts_with_make_demo_and_make_test() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 150
    block = lines[lines.index("```") + 1 :]
    block = block[: block.index("```")]
    assert [line.split()[:2] for line in block] == [["make", "demo"], ["make", "test"]]
    assert "```" in lines[:4]  # the block comes first, under the title


def test_readme_links_and_images_point_at_committed_files() -> None:
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README.read_text())
    local = [t for t in targets if "://" not in t]
    assert local, "the README links into docs/"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, missing
