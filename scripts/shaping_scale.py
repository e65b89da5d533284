"""How large Eq. 10's distance is on the training pairs, the scale to read a transfer run's
shaping term against.

For each shaped method of a finished ``pved protocol`` directory, this loads the model the
protocol selected (its chosen initialisation) and the pair's paired dataset, and computes
the distance D of Eq. 10 (the KL between the shared posteriors, or a point-code model's
squared distance) on

* the matched pairs the model was trained on (source step with its own target step), and
* the same rows with the target side shuffled (a source step against an unrelated target
  step of the training data): what D is between codes that have nothing to do with each
  other.

A transfer run whose D on the target task stays near the shuffled level has not brought
the target's shared codes any closer to the source's than chance. The rows are a seeded
sample, so the numbers are reproducible.

    .venv/bin/python scripts/shaping_scale.py reports/jaco-fetch-quick

Prints a Markdown table and writes ``PROTOCOL_DIR/subspaces/shaping_scale.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved.experiments.stages import default_dataset_path, default_model_path
from pved.models.registry import load_model
from pved.pairing.dataset import load_dataset
from pved.runs import atomic_write_json

QUANTILES = (0.5, 0.95)


def distance_stats(distance: np.ndarray) -> dict[str, float]:
    """Mean, median and 95% quantile of per-row distances (R,)."""
    return {
        "mean": float(distance.mean()),
        **{f"q{round(q * 100)}": float(np.quantile(distance, q)) for q in QUANTILES},
    }


@torch.no_grad()
def shaping_scale(
    model_path: Path, dataset_path: Path, rows: int, seed: int
) -> dict[str, dict[str, float]]:
    """D of Eq. 10 on ``rows`` sampled training pairs, matched and with the target side
    shuffled: ``{"matched": stats, "shuffled": stats}`` (:func:`distance_stats`)."""
    dataset = load_dataset(dataset_path)
    model = load_model(model_path).eval()
    x_s, x_t = dataset.model_inputs()
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False)
    shuffled = rng.permutation(pick)
    source = torch.as_tensor(x_s[pick], dtype=torch.float32)
    out = {}
    for name, target_rows in (("matched", pick), ("shuffled", shuffled)):
        target = torch.as_tensor(x_t[target_rows], dtype=torch.float32)
        out[name] = distance_stats(model.shaping(source, target).double().numpy())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", type=Path, help="a finished `pved protocol` output directory")
    parser.add_argument("--rows", type=int, default=20_000, help="training pairs sampled")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    summary_file = args.protocol / "summary.json"
    if not summary_file.is_file():
        sys.exit(f"{args.protocol}: no summary.json (not a finished `pved protocol` output)")
    summary = json.loads(summary_file.read_text())
    runs_root = args.protocol / "runs"
    result: dict[str, Any] = {"rows": args.rows, "seed": args.seed, "pairs": {}}
    print("| pair | method | init | D matched: median / mean | D shuffled: median / mean |")
    print("|---|---|---|---|---|")
    for pair, entry in summary["pairs"].items():
        dataset = default_dataset_path(pair, runs_root)
        if not dataset.is_file():
            sys.exit(f"{dataset}: the pair's paired dataset is not in this directory")
        for method, state in entry["methods"].items():
            init = state.get("init")
            if init is None:  # plain PPO and the oracle have no model
                continue
            model = default_model_path(pair, method, runs_root, seed=init)
            if not model.is_file():
                sys.exit(f"{model}: the selected model is not in this directory")
            scale = shaping_scale(model, dataset, args.rows, args.seed)
            result["pairs"].setdefault(pair, {})[method] = {"init": init, **scale}
            m, s = scale["matched"], scale["shuffled"]
            print(
                f"| {pair} | {method} | {init} | {m['q50']:.3g} / {m['mean']:.3g} | "
                f"{s['q50']:.3g} / {s['mean']:.3g} |"
            )
    out = args.protocol / "subspaces" / "shaping_scale.json"
    out.parent.mkdir(exist_ok=True)
    atomic_write_json(out, result)
    print(out)


if __name__ == "__main__":
    main()
