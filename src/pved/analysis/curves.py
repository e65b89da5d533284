"""Learning curves over environment steps: mean and 95% confidence interval over seeds."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from pved.errors import PvedError


@dataclass
class Curve:
    """One method's curve: ``values`` (seeds, points) at env ``steps`` (points,)."""

    method: str
    steps: np.ndarray
    values: np.ndarray
    seeds: list[int]

    @property
    def mean(self) -> np.ndarray:
        return np.asarray(self.values.mean(0))

    @property
    def ci95(self) -> np.ndarray:
        """Half-width of the 95% t-interval of the mean over seeds (0 for one seed)."""
        n = self.values.shape[0]
        if n < 2:
            return np.zeros(self.values.shape[1])
        sem = self.values.std(0, ddof=1) / np.sqrt(n)
        return np.asarray(stats.t.ppf(0.975, n - 1) * sem)


def mean_ci(values: np.ndarray) -> tuple[float, float]:
    """Mean and 95% t-interval half-width of a 1-D sample."""
    values = np.asarray(values, dtype=np.float64)
    if values.size < 2:
        return float(values.mean()), 0.0
    sem = values.std(ddof=1) / np.sqrt(values.size)
    return float(values.mean()), float(stats.t.ppf(0.975, values.size - 1) * sem)


def read_eval_points(metrics_path: Path, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of the records in ``metrics.jsonl`` that carry ``key``."""
    steps, values = [], []
    for line in Path(metrics_path).read_text().splitlines():
        if not line.strip():
            continue
        record = json.loads(line)
        if record.get(key) is not None:
            steps.append(int(record["step"]))
            values.append(float(record[key]))
    return np.asarray(steps), np.asarray(values)


def load_curve(method: str, run_dirs: list[Path], seeds: list[int], key: str) -> Curve:
    """Stack the evaluation points of several seeds' runs (same schedule) into a curve."""
    series = [read_eval_points(d / "metrics.jsonl", key) for d in run_dirs]
    if not series or any(len(s[0]) == 0 for s in series):
        raise PvedError(f"no {key!r} evaluation points in the runs of {method}")
    n = min(len(s[0]) for s in series)
    steps = series[0][0][:n]
    values = np.stack([s[1][:n] for s in series])
    return Curve(method, steps, values, list(seeds))


def plot_curves(
    curves: list[Curve],
    path: Path,
    ylabel: str,
    title: str,
    bounds: tuple[float, float] | None = None,
) -> Path:
    """Mean ± 95% CI per method over env steps, each seed's curve faintly behind it,
    saved as PNG. ``bounds``: the metric's range (e.g. (0, 1) for a success rate); the
    t-interval, which knows no bounds, is drawn clipped to it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    for curve in curves:
        mean, ci = curve.mean, curve.ci95
        low, high = mean - ci, mean + ci
        if bounds is not None:
            low, high = np.clip(low, *bounds), np.clip(high, *bounds)
        (line,) = ax.plot(curve.steps, mean, label=f"{curve.method} (n={len(curve.seeds)})")
        ax.fill_between(curve.steps, low, high, alpha=0.2, color=line.get_color())
        for seed_values in curve.values:
            ax.plot(curve.steps, seed_values, color=line.get_color(), alpha=0.25, lw=0.7)
    if bounds is not None:
        margin = 0.03 * (bounds[1] - bounds[0])
        ax.set_ylim(bounds[0] - margin, bounds[1] + margin)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)
    return path
