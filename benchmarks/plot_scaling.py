"""The protocol runner's measured scaling as a figure (docs/scale.md, "How it scales").

The numbers are those of ``benchmarks/protocol_scaling.py`` as recorded in the journal
(docs/journal/engineering.md, "The protocol runner (issue 6)"; the 16-core row also in
docs/journal/protocol-runs.md, "The scaling row, at last"); nothing is measured here.
Add a row when you measure another machine, then run

    .venv/bin/python benchmarks/plot_scaling.py      # writes docs/figures/protocol-scaling.png
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


class Row(NamedTuple):
    """One machine's two passes of the same grid of plain-PPO transfer runs."""

    machine: str
    workers: int  # the parallel pass's
    grid: str  # the command's grid
    wall_one_s: float  # the whole grid on 1 worker
    wall_all_s: float  # ... on ``workers``
    rate_one: float  # env steps/s on 1 worker
    rate_all: float  # ... on ``workers``
    speedup: float  # as printed by the benchmark (from the unrounded walls)


ROWS = (
    Row("this project's 2-core VM (Ray)", 2, "4 runs x 50k steps", 46.8, 27.0, 4277, 7421, 1.74),
    Row(
        "16-CPU device machine (processes)",
        16,
        "16 runs x 20k steps",
        46.3,
        10.7,
        6911,
        29831,
        4.32,
    ),
)

OUT = Path(__file__).resolve().parents[1] / "docs" / "figures" / "protocol-scaling.png"


def plot(out: Path) -> Path:
    """Speed-up against workers (with the ideal), and env steps/s of both passes."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(8.0, 3.2), dpi=100)
    top = max(r.workers for r in ROWS)
    left.plot([1, top], [1, top], "--", color="0.6", label="ideal")
    for row in ROWS:
        left.plot([1, row.workers], [1, row.speedup], "o-", label=f"{row.machine}: {row.speedup}")
    left.set(xscale="log", yscale="log", xlabel="workers", ylabel="speed-up over 1 worker")
    left.set_xticks([1, 2, 4, 8, 16], labels=["1", "2", "4", "8", "16"])
    left.set_yticks([1, 2, 4, 8, 16], labels=["1", "2", "4", "8", "16"])
    left.legend(fontsize=7, loc="upper left")
    names = [f"{r.machine.split(' (')[0]}\n{r.grid}" for r in ROWS]
    x = range(len(ROWS))
    right.bar([i - 0.2 for i in x], [r.rate_one for r in ROWS], 0.4, label="1 worker")
    right.bar([i + 0.2 for i in x], [r.rate_all for r in ROWS], 0.4, label="all workers")
    right.set_xticks(list(x), labels=names, fontsize=7)
    right.set_ylabel("env steps / s (whole grid)")
    right.legend(fontsize=7)
    fig.suptitle("pved protocol runner: the same transfer runs on 1 worker and on all", size=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    print(plot(parser.parse_args().out))


if __name__ == "__main__":
    main()
