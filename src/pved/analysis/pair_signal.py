"""``pved pair signal``: does a pair's pairing relate its two agents? Asked before any
model is trained or transfer run is spent on it.

Eq. 10's term can only steer the target if the model's shared space puts a target step
near its partner source step, and the model can only learn that from paired data in which
one agent's step says something about the other's. This collects a few paired episodes of
the pair (its policies on its training task, its alignment; :func:`collect_pairs`) and
measures what :mod:`pved.analysis.pairing_signal` measures for a finished protocol: the
held-out R² of a ridge regression of one agent's standardised step (robot state and
action) on its partner's, each way, beside the same with the partners shuffled (the
floor, about 0). Linear, so a lower bound on the relation. A pairing that relates the
agents is needed, not enough: on the built-in pairs' full datasets the arms' pairings
relate them strongly (R² 0.70 reacher, 0.72 jaco-fetch) and the legs' weakly (0.14
walker-hopper, 0.09 humanoid-ant), and transfer pays on walker-hopper alone
(docs/journal/across-pairs.md).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from pved.analysis.pairing_signal import pairing_r2
from pved.checks import check_int, check_seed
from pved.experiments.stages import collect_pairs
from pved.pairing.dataset import load_dataset
from pved.spec import get_preset

#: How the held-out R² (source → target, less the shuffled floor) is read: at or above
#: the first "strongly", above the second "weakly", else "not" (a reading, not a test; the
#: built-in pairs sit at 0.70-0.72 and 0.09-0.14).
STRONG_R2, WEAK_R2 = 0.5, 0.05


def pair_signal(
    pair: str,
    *,
    episodes: int = 100,
    rows: int = 20_000,
    seed: int = 0,
    runs_root: Path | None = None,
) -> dict[str, Any]:
    """Collect ``episodes`` paired episodes of ``pair`` (a built-in name or a spec file),
    into ``runs_root`` if given (kept, and reused when run again) or a temporary folder,
    and return ``{"pair", "episodes", "rows", "alignment", "r2": {"source_to_target",
    "target_to_source", "source_to_shuffled_target"}, "reading"}``. The options are
    checked before anything is collected."""
    check_int("--episodes", episodes, low=HELD_OUT_MIN_EPISODES)
    check_int("--rows", rows, low=100)
    check_seed("--seed", seed)
    preset = get_preset(pair)
    with tempfile.TemporaryDirectory(prefix="pved-signal-") as tmp:
        root = Path(tmp) if runs_root is None else Path(runs_root)
        path = collect_pairs(pair, episodes=episodes, seed=seed, runs_root=root, progress=False)
        dataset = load_dataset(path)
    x_s, x_t = dataset.model_inputs()
    r2 = pairing_r2(x_s, x_t, dataset.episode, rows, seed)
    gain = r2["source_to_target"] - r2["source_to_shuffled_target"]
    level = "strongly" if gain >= STRONG_R2 else "weakly" if gain > WEAK_R2 else "not"
    reading = f"the pairing relates the agents {level} (R² {gain:.2f} above the shuffled floor)"
    if level == "not":
        reading += ": a model of these pairs has nothing to share, and Eq. 10 nothing to steer by"
    return {
        "pair": preset.name,
        "episodes": episodes,
        "rows": int(min(rows, len(x_s))),
        "alignment": str(dataset.header.get("alignment")),
        "r2": r2,
        "reading": reading,
    }


#: The regression holds out every tenth episode: with fewer than 20, too few are held out.
HELD_OUT_MIN_EPISODES = 20


def format_signal(result: dict[str, Any]) -> str:
    """The result of :func:`pair_signal` as a Markdown table and its reading."""
    r2 = result["r2"]
    return "\n".join(
        [
            f"{result['pair']}: {result['episodes']} paired episodes "
            f"({result['alignment']} alignment), {result['rows']:,} rows, held-out ridge R²",
            "",
            "| source → target | target → source | source → shuffled target |",
            "|---|---|---|",
            f"| {r2['source_to_target']:.3f} | {r2['target_to_source']:.3f} "
            f"| {r2['source_to_shuffled_target']:.3f} |",
            "",
            result["reading"][0].upper() + result["reading"][1:] + ".",
        ]
    )


__all__ = ["STRONG_R2", "WEAK_R2", "format_signal", "pair_signal"]
