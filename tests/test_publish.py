"""``pved publish``: the tables of results in README.md, docs/results.md and
docs/results/<pair>.md are what the committed records make (regenerated in memory here),
and a record that changes leaves its page stale until ``pved publish`` runs again."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.curves import REPS, SEED, bootstrap_mean
from pved.analysis.publish import PAGES, Records, publish, render_page, stale_pages
from pved.errors import PvedError

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # every published table at the project's resample count (~25 s of CPU)
def test_every_page_matches_its_records() -> None:
    """Fails when a table was typed or edited by hand, or a record changed since the last
    `pved publish` (its message names the pages: run `make publish-docs`)."""
    assert all((ROOT / page).is_file() for page in PAGES)
    assert stale_pages(ROOT) == [], "run `make publish-docs` (pved publish)"


def write_protocol(root: Path, name: str, finals: dict[str, list[float]]) -> Path:
    """A committed record ``docs/protocol/NAME/summary.json`` of one reacher protocol:
    a shaped method's 15 runs named as a protocol names them (3 source policies x 5
    seeds), plain PPO's 15 runs a seed each."""
    methods: dict[str, Any] = {}
    for method, values in finals.items():
        runs = []
        for i, value in enumerate(values):
            if method == "ppo":
                seed, key = 20000 + i, f"reacher/transfer/ppo/seed{20000 + i}"
            else:
                seed = 20000 * (1 + i % 5)
                key = f"reacher/transfer/{method}-beta0.01-init0-src{i // 5}/seed{seed}"
            runs.append({"key": key, "seed": seed, "success_rate": value})
        methods[method] = {
            "runs_planned": len(values),
            "runs_finished": len(values),
            "runs": runs,
            "final": {"iqm": 0.5, "iqm_ci": [0.25, 0.75]},
            **({"beta": 0.01, "init": 0} if method != "ppo" else {}),
        }
    directory = root / "docs" / "protocol" / name
    directory.mkdir(parents=True, exist_ok=True)
    summary = {
        "budget": "quick",
        "pairs": {"reacher": {"metric": "success_rate", "methods": methods}},
    }
    (directory / "summary.json").write_text(json.dumps(summary))
    return directory


PAGE = """# Results

<!-- pved:table intervals -->
<!-- /pved:table -->

Prose the tables leave alone.

<!-- pved:table finals reacher-quick -->
old numbers typed by hand
<!-- /pved:table -->

<!-- pved:table difference reacher-quick pved ppo -->
<!-- /pved:table -->
"""


@pytest.fixture
def small_root(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    write_protocol(
        tmp_path,
        "reacher-quick",
        {"pved": list(rng.uniform(0.3, 1.0, 15)), "ppo": list(rng.uniform(0.0, 0.6, 15))},
    )
    (tmp_path / "docs" / "results.md").write_text(PAGE)
    return tmp_path


def test_a_changed_record_makes_its_page_stale_until_published(
    small_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    page = small_root / "docs" / "results.md"
    assert stale_pages(small_root) == ["docs/results.md"]  # typed by hand: stale
    assert publish(small_root) == ["docs/results.md"]
    assert stale_pages(small_root) == [] and publish(small_root) == []
    text = page.read_text()
    assert "Prose the tables leave alone." in text and "typed by hand" not in text
    assert f"{REPS:,} resamples, seed {SEED}" in text
    # the finals table prints each method's own two-level interval
    record = small_root / "docs" / "protocol" / "reacher-quick" / "summary.json"
    summary = json.loads(record.read_text())
    runs = summary["pairs"]["reacher"]["methods"]["pved"]["runs"]
    x = np.array([r["success_rate"] for r in runs])
    sources = [i // 5 for i in range(15)]
    mean = bootstrap_mean(x, [r["seed"] for r in runs], sources, label=("reacher", "pved"))
    lo, hi = mean["mean_ci"]
    assert f"| pved | 15/15 | {mean['mean']:.3f} [{lo:.3f}, {hi:.3f}] | 0.500" in text

    runs[0]["success_rate"] = 1.0 - runs[0]["success_rate"]  # one run's final changes
    record.write_text(json.dumps(summary))
    assert stale_pages(small_root) == ["docs/results.md"]
    code, _, err = run_cli(capsys, "publish", "--root", small_root, "--check")
    assert code == 2 and "docs/results.md" in err and "run pved publish" in err
    code, out, _ = run_cli(capsys, "publish", "--root", small_root)
    assert code == 0 and "1 page(s) changed: docs/results.md" in out
    assert stale_pages(small_root) == [] and page.read_text() != text


def test_bad_pages_and_roots_are_refused(
    small_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = Records(small_root)
    with pytest.raises(PvedError, match="unknown table 'nonsense'"):
        render_page(rec, "p.md", "<!-- pved:table nonsense -->\n<!-- /pved:table -->\n")
    with pytest.raises(PvedError, match="without its close"):
        render_page(rec, "p.md", "<!-- pved:table intervals -->\nno close\n")
    with pytest.raises(PvedError, match="wrong arguments"):
        render_page(rec, "p.md", "<!-- pved:table finals -->\n<!-- /pved:table -->\n")
    code, _, err = run_cli(capsys, "publish", "--root", tmp_path / "nowhere")
    assert code == 2 and "no docs/protocol/" in err
