"""Learning-curve statistics: the 95% interval is the t-interval over seeds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pved.analysis.curves import load_curve, mean_ci, plot_curves


def test_mean_ci_matches_hand_computation() -> None:
    values = np.array([0.2, 0.4, 0.6])
    mean, half = mean_ci(values)
    # t_{0.975, 2} = 4.302653; sd = 0.2; sem = 0.2 / sqrt(3)
    np.testing.assert_allclose(mean, 0.4)
    np.testing.assert_allclose(half, 4.302653 * 0.2 / np.sqrt(3), rtol=1e-5)
    assert mean_ci(np.array([1.0])) == (1.0, 0.0)


def test_curve_from_metrics_and_plot(tmp_path: Path) -> None:
    dirs = []
    for seed, offset in ((1, 0.0), (2, 0.2)):
        d = tmp_path / f"seed{seed}"
        d.mkdir()
        lines = [{"step": 10, "loss": 1.0}]
        lines += [{"step": s, "eval/success_rate": offset + s / 100} for s in (0, 50, 100)]
        (d / "metrics.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n")
        dirs.append(d)
    curve = load_curve("pved", dirs, [1, 2], "eval/success_rate")
    assert curve.steps.tolist() == [0, 50, 100]
    np.testing.assert_allclose(curve.mean, [0.1, 0.6, 1.1])
    out = plot_curves([curve], tmp_path / "c.png", "success", "t")
    assert out.stat().st_size > 1000
