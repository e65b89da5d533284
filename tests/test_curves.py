"""Learning-curve statistics: the two-level bootstrap of a mean and of a difference, and the
one-level (rliable) intervals of the IQM and the curve bands."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from scipy import stats

import pved.analysis.bootstrap as bootstrap
from pved.analysis.curves import (
    REPS,
    Curve,
    Panel,
    bootstrap_difference,
    bootstrap_mean,
    bootstrap_summary,
    load_curve,
    panels_figure,
    plot_curves,
    plot_panels,
    reward_scale,
    steps_to_baseline_finals,
    steps_to_reach,
)
from pved.errors import PvedError

SAMPLE = np.array([0.1, 0.2, 0.4, 0.5, 0.9, 1.0, 0.3, 0.7])


def width(ci: object) -> float:
    lo, hi = ci  # type: ignore[misc]
    return float(hi - lo)


def test_bootstrap_summary_point_estimates_match_hand_computation() -> None:
    s = bootstrap_summary(SAMPLE, reps=500)
    assert s["runs"] == 8
    np.testing.assert_allclose(s["mean"], SAMPLE.mean())
    # IQM: sorted 0.1 0.2 | 0.3 0.4 0.5 0.7 | 0.9 1.0 -> mean of the middle four
    np.testing.assert_allclose(s["iqm"], (0.3 + 0.4 + 0.5 + 0.7) / 4)
    np.testing.assert_allclose(s["iqm"], stats.trim_mean(SAMPLE, 0.25))
    for key, point in (("mean_ci", "mean"), ("iqm_ci", "iqm")):
        lo, hi = s[key]  # type: ignore[misc]
        assert lo < s[point] < hi  # type: ignore[operator]
        # a bootstrap of a mean/trimmed mean stays inside the data's range
        assert SAMPLE.min() <= lo and hi <= SAMPLE.max()


def test_bootstrap_ci_narrows_with_more_runs() -> None:
    rng = np.random.default_rng(7)
    small = bootstrap_summary(rng.normal(0.0, 1.0, 8), reps=1000)
    large = bootstrap_summary(rng.normal(0.0, 1.0, 400), reps=1000)
    assert width(large["mean_ci"]) < 0.5 * width(small["mean_ci"])
    assert width(large["iqm_ci"]) < 0.5 * width(small["iqm_ci"])


def test_bootstrap_summary_is_reproducible_and_leaves_global_rng_alone() -> None:
    # the global RNG on purpose: it is what rliable draws from
    np.random.seed(123)  # noqa: NPY002
    expected_next = np.random.random()  # noqa: NPY002
    np.random.seed(123)  # noqa: NPY002
    a = bootstrap_summary(SAMPLE, reps=300, seed=4)
    assert np.random.random() == expected_next  # noqa: NPY002  (caller's stream untouched)
    b = bootstrap_summary(SAMPLE, reps=300, seed=4)
    c = bootstrap_summary(SAMPLE, reps=300, seed=5)
    assert a == b
    assert a["mean_ci"] != c["mean_ci"]  # the seed is what makes it reproducible


def test_bootstrap_summary_degenerate_and_bad_input() -> None:
    one = bootstrap_summary(np.array([0.7]))
    assert one == {"runs": 1, "mean": 0.7, "iqm": 0.7, "mean_ci": [0.7, 0.7], "iqm_ci": [0.7, 0.7]}
    for bad in (np.array([0.1, np.nan, 0.3]), np.array([0.1, np.inf]), np.array([])):
        with pytest.raises(PvedError) as info:
            bootstrap_summary(bad)
        assert "\n" not in str(info.value)


def toy_curve(values: list[list[float]], method: str = "m") -> Curve:
    v = np.asarray(values, dtype=np.float64)
    return Curve(method, np.arange(v.shape[1]) * 100, v, list(range(v.shape[0])))


def test_band_brackets_the_mean_and_is_zero_where_runs_agree() -> None:
    rng = np.random.default_rng(0)
    values = rng.uniform(0.0, 1.0, (5, 6))
    values[:, 2] = 0.4  # every run agrees at this step
    curve = toy_curve(values.tolist())
    lo, hi = curve.band(reps=500)
    mean = curve.mean
    assert lo.shape == hi.shape == mean.shape == (6,)
    assert np.all(lo <= mean) and np.all(mean <= hi)
    assert hi[2] - lo[2] == 0.0 and lo[2] == pytest.approx(0.4)
    others = np.delete(hi - lo, 2)
    assert np.all(others > 0)
    same_lo, same_hi = curve.band(reps=500)
    np.testing.assert_array_equal(lo, same_lo)
    np.testing.assert_array_equal(hi, same_hi)
    one_lo, one_hi = toy_curve(values[:1].tolist()).band()
    np.testing.assert_array_equal(one_lo, values[0])
    np.testing.assert_array_equal(one_hi, values[0])
    with pytest.raises(PvedError):
        toy_curve([[0.1, np.nan], [0.2, 0.3]]).band()


def test_steps_to_reach_first_step_at_or_above_threshold() -> None:
    # mean over the two runs: 0, 0.25, 0.5, 0.5 at steps 0, 100, 200, 300
    curve = toy_curve([[0.0, 0.25, 0.5, 0.75], [0.0, 0.25, 0.5, 0.25]])
    assert steps_to_reach(curve, 0.5) == 200  # reached with equality, first of two
    assert steps_to_reach(curve, 0.3) == 200
    assert steps_to_reach(curve, 0.0) == 0
    assert steps_to_reach(curve, 0.75) is None  # one run gets there, the mean does not


def test_steps_to_baseline_finals_skips_a_baseline_that_learned_nothing() -> None:
    # walker-hopper's case: PPO ends below where it started, the oracle learns
    ppo = toy_curve([[0.0, -0.2, -0.5, -0.6]], "ppo")
    oracle = toy_curve([[0.0, 1.0, 3.0, 5.0]], "oracle")
    pved = toy_curve([[0.0, 2.0, 6.0, 7.0]], "pved")
    reach = steps_to_baseline_finals([pved, ppo, oracle], ("ppo", "oracle"))
    assert reach["pved"] == {"ppo_improved": False, "oracle_final": 5.0,
                             "steps_to_oracle_final": 200}  # fmt: skip
    assert reach["ppo"]["steps_to_oracle_final"] is None  # never gets there
    assert reach["oracle"]["steps_to_oracle_final"] == 300
    # a baseline that learned: every method gets the step count, as steps_to_reach gives it
    learned = toy_curve([[0.0, 1.0, 2.0, 2.5]], "ppo")
    reach = steps_to_baseline_finals([pved, learned], ("ppo", "oracle"))
    assert reach["pved"] == {"ppo_final": 2.5, "steps_to_ppo_final": 200}
    assert reach["ppo"]["steps_to_ppo_final"] == 300


def write_rollouts(run_dir: Path, rows: list[tuple[float, float]]) -> Path:
    """A transfer run's metrics.jsonl: an evaluation row, then one row per rollout with
    its (shaping, env reward) means, then another evaluation row."""
    run_dir.mkdir(parents=True)
    lines = [{"step": 0, "eval/success_rate": 0.0}]
    lines += [
        {"step": 2048 * (i + 1), "rollout/reward_shaping": sh, "rollout/env_reward": env}
        for i, (sh, env) in enumerate(rows)
    ]
    lines.append({"step": 2048 * len(rows), "eval/success_rate": 0.5})
    (run_dir / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    return run_dir


def test_reward_scale_averages_first_and_last_rollouts_over_runs(tmp_path: Path) -> None:
    a = write_rollouts(tmp_path / "a", [(-188.0, 0.0), (-3.0, 0.1), (-2.0, 0.5)])
    b = write_rollouts(tmp_path / "b", [(-12.0, 0.0), (-1.0, 0.3)])
    scale = reward_scale([a, b])
    assert scale == {"shaping_first": -100.0, "shaping_last": -1.5,
                     "env_reward_first": 0.0, "env_reward_last": 0.4, "runs": 2}  # fmt: skip
    # runs without a shaping term (plain PPO) or without metrics are left out
    ppo = tmp_path / "ppo"
    ppo.mkdir()
    (ppo / "metrics.jsonl").write_text('{"step": 0, "eval/success_rate": 0.0}\n')
    assert reward_scale([a, ppo, tmp_path / "missing"]) == reward_scale([a])
    assert reward_scale([ppo]) is None and reward_scale([]) is None


def test_reward_scale_last_share_averages_each_runs_last_rollouts(tmp_path: Path) -> None:
    rows = [(-9.0, 5.0)] * 8 + [(-2.0, 1.0), (-4.0, 3.0)]
    a = write_rollouts(tmp_path / "a", rows)
    scale = reward_scale([a], last_share=0.2)  # the last two of ten
    assert scale is not None
    assert (scale["shaping_last"], scale["env_reward_last"]) == (-3.0, 2.0)
    assert scale["shaping_first"] == -9.0  # the first rollout stays the first
    # a share smaller than one rollout still takes the last one; 0 is the default's
    last_only = reward_scale([a], last_share=0.01)
    assert last_only == reward_scale([a]) and last_only is not None
    assert last_only["shaping_last"] == -4.0
    every = reward_scale([a], last_share=1.0)
    assert every is not None and every["shaping_last"] == pytest.approx(-7.8)
    with pytest.raises(PvedError, match="last_share"):
        reward_scale([a], last_share=1.5)


def two_panels() -> list[Panel]:
    rng = np.random.default_rng(1)
    panels = []
    for title in ("reacher", "arm"):
        curves = [
            toy_curve(rng.uniform(0, 1, (n, 5)).tolist(), method)
            for method, n in (("ppo", 3), ("pved", 2))
        ]
        panels.append(Panel(title, "success rate", curves, bounds=(0.0, 1.0)))
    return panels


def test_panels_figure_layout_colours_and_legend() -> None:
    panels = two_panels()
    fig = panels_figure(panels, reps=100)
    try:
        assert len(fig.axes) == 2
        assert [ax.get_title() for ax in fig.axes] == ["reacher", "arm"]
        left, right = (ax.get_position() for ax in fig.axes)
        assert left.x1 <= right.x0 and left.y0 == pytest.approx(right.y0)  # side by side
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert texts == ["ppo (n=3)", "pved (n=2)"]
        # the same method has the same colour in both panels, the two methods differ
        colours = [
            {line.get_color() for line in ax.get_lines() if line.get_alpha() is None}
            for ax in fig.axes
        ]
        assert colours[0] == colours[1] and len(colours[0]) == 2
    finally:
        plt.close(fig)
    fig = panels_figure(panels * 2 + panels[:1], reps=20)  # 5 panels: 2 rows of 3, one empty
    try:
        assert len(fig.axes) == 5
        assert len({round(ax.get_position().y0, 3) for ax in fig.axes}) == 2
    finally:
        plt.close(fig)


def test_plot_panels_writes_png_atomically(tmp_path: Path) -> None:
    out = plot_panels(two_panels(), tmp_path / "fig" / "fig3.png", reps=100)
    assert out == tmp_path / "fig" / "fig3.png"
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 1000
    assert [p.name for p in out.parent.iterdir()] == ["fig3.png"]  # no temp file left
    with pytest.raises(PvedError):
        plot_panels([], tmp_path / "empty.png")


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


# ---- the difference of two groups: a two-level bootstrap over sources and seeds

SEEDS = [20000, 40000, 60000, 80000, 100000]


def crossed(by_source: list[float], by_seed: list[float]) -> tuple[np.ndarray, list, list]:
    """Runs of a shaped method, every seed with every source: (scores, seeds, sources),
    the score of (source k, seed s) by_source[k] + by_seed[s]."""
    cells = [(k, s) for k in range(len(by_source)) for s in range(len(by_seed))]
    scores = np.array([by_source[k] + by_seed[s] for k, s in cells])
    return scores, [SEEDS[s] for _, s in cells], [k for k, _ in cells]


def test_sources_that_differ_widen_the_interval_beyond_the_seeds() -> None:
    """Three source policies end at 0.0, 0.1 and 1.0 and the seeds change nothing: the
    seeds alone see a sure gain of 1/6 over a constant 0.2, but a resample that draws
    only the two weak sources ((2/3)^3 = 30% of them) ends below 0.2."""
    a, seeds, sources = crossed([0.0, 0.1, 1.0], [0.0] * 5)
    b, b_seeds = np.full(15, 0.2), list(range(15))
    seed_only = bootstrap_difference(a, b, seeds_a=seeds, seeds_b=b_seeds)
    both = bootstrap_difference(a, b, seeds_a=seeds, seeds_b=b_seeds, sources_a=sources)
    assert seed_only["diff"] == pytest.approx(both["diff"]) == pytest.approx(1.1 / 3 - 0.2)
    assert seed_only["diff_ci"] == pytest.approx([1.1 / 3 - 0.2] * 2)  # excludes 0
    assert seed_only["tests"][0]["p"] == pytest.approx(2 / (REPS + 1))
    lo, hi = both["diff_ci"]
    assert lo < 0 < hi and width(both["diff_ci"]) > 0.5
    # the k/3 means of three draws: 0.0 to 1.0, the middle 95% from the weakest to the best
    assert both["a"]["mean_ci"] == pytest.approx([0.0, 1.0])
    assert (both["a"]["sources"], both["a"]["seeds"], both["b"]["sources"]) == (3, 5, 0)
    assert both["tests"][0]["p"] > 0.5  # 30% of the resamples at or below 0, p = 2 x 0.3


def test_equal_sources_leave_the_seed_interval() -> None:
    """Sources that all score alike add nothing: the two-level interval is the seed
    bootstrap's (up to the resampling's noise)."""
    a, seeds, sources = crossed([0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 1.0, 0.0])
    b = np.zeros(15)
    seed_only = bootstrap_difference(a, b, reps=4000, seeds_a=seeds, seeds_b=list(range(15)))
    both = bootstrap_difference(
        a, b, reps=4000, seeds_a=seeds, seeds_b=list(range(15)), sources_a=sources
    )
    assert abs(width(both["diff_ci"]) - width(seed_only["diff_ci"])) < 0.05
    assert width(both["diff_ci"]) > 0.5


def test_shared_sources_are_drawn_once_for_both_groups() -> None:
    """Two shaped methods with the same source effect (1.0 for source 2, 0 otherwise)
    and A 0.5 above B everywhere: one source draw for both leaves the difference at 0.5
    in every resample; drawn apart (different source labels), it spreads by ±1."""
    a, seeds, sources = crossed([0.5, 0.5, 1.5], [0.0] * 5)
    b = a - 0.5
    shared = bootstrap_difference(
        a, b, seeds_a=seeds, seeds_b=seeds, sources_a=sources, sources_b=sources
    )
    assert shared["diff_ci"] == pytest.approx([0.5, 0.5])
    apart = bootstrap_difference(
        a, b, seeds_a=seeds, seeds_b=seeds, sources_a=sources, sources_b=[s + 3 for s in sources]
    )
    assert apart["diff_ci"][0] < 0 < 1 < apart["diff_ci"][1]


def test_bootstrap_p_values_of_a_bar() -> None:
    """P(d* <= c) and P(d* >= c) as (1 + count) / (1 + reps), p = 2 min of them."""
    # a = {0, 1}, b = 0: the resampled mean of a is 0, 0.5 or 1 with chances 1/4, 1/2, 1/4
    d = bootstrap_difference(np.array([0.0, 1.0]), np.zeros(2), reps=20000, bars=(0.0, 1.0))
    at0, at1 = d["tests"]
    assert (at0["bar"], at1["bar"]) == (0.0, 1.0)
    assert at0["le"] == pytest.approx(0.25, abs=0.01) and at0["ge"] == 1.0
    assert at0["p"] == pytest.approx(0.5, abs=0.02)
    assert at1["ge"] == pytest.approx(0.25, abs=0.01) and at1["p"] == pytest.approx(0.5, abs=0.02)
    # every resample above the bar: the smallest p there is, 2 / (reps + 1)
    far = bootstrap_difference(np.array([1.0, 1.1]), np.array([0.0, 0.1]), reps=999)
    assert far["tests"][0] == {"bar": 0.0, "le": 1 / 1000, "ge": 1.0, "p": 2 / 1000}
    # draws within tol of the bar count on both sides: no evidence either way
    tie = bootstrap_difference(np.full(3, 0.1), np.full(5, 0.1), bars=(0.0,), tol=1e-9)
    assert tie["tests"][0]["p"] == 1.0
    # a group's own mean against a bar
    g = bootstrap_difference(np.array([0.0, 1.0]), np.zeros(2), reps=20000, group_bars=(0.5,))
    assert g["a"]["tests"][0]["le"] == pytest.approx(0.75, abs=0.01)
    assert "tests" not in d["a"]


def test_a_methods_interval_is_the_same_whatever_it_is_compared_with() -> None:
    """A group's resamples are its own: bootstrap_mean's interval is the one it has in any
    comparison, first or second, beside a shaped method or not (reacher's 15 PPO runs
    once carried lower bounds 0.199 and 0.140 on two pages), and a rerun or another
    process gives the same bounds."""
    ppo = np.array([1.0, 0.0, 0.0, 0.036, 0.0, 0.994, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0])
    shaped, seeds, sources = crossed([0.0, 0.2, 0.9], [0.0, 0.1, 0.0, 0.0, 0.0])
    alone = bootstrap_mean(ppo, seeds=list(range(15)))
    bootstrap._CACHE.clear()  # drawn again, not read back
    assert alone == bootstrap_mean(ppo, seeds=list(range(15)))  # a rerun: the same bounds
    assert (alone["runs"], alone["seeds"], alone["sources"]) == (15, 15, 0)
    first = bootstrap_difference(ppo, shaped, seeds_a=list(range(15)), seeds_b=seeds)
    after = bootstrap_difference(
        shaped, ppo, seeds_a=seeds, sources_a=sources, seeds_b=list(range(15))
    )
    assert alone["mean_ci"] == first["a"]["mean_ci"] == after["b"]["mean_ci"]
    two = bootstrap_mean(shaped, seeds=seeds, sources=sources)
    assert two["mean_ci"] == after["a"]["mean_ci"] and two["sources"] == 3
    few = [bootstrap_mean(ppo, list(range(15)), reps=200, seed=k)["mean_ci"] for k in (0, 1)]
    assert few[0] != few[1]  # at few resamples the seed moves it
    with pytest.raises(PvedError, match="need seed labels"):
        bootstrap_mean(shaped, sources=sources)


def test_two_level_bootstrap_bad_labels() -> None:
    a, seeds, sources = crossed([0.0, 1.0], [0.0, 0.0])
    with pytest.raises(PvedError, match="need seed labels"):
        bootstrap_difference(a, a, sources_a=sources)
    with pytest.raises(PvedError, match="source labels for 4 runs"):
        bootstrap_difference(a, a, seeds_a=seeds, sources_a=sources[:3])
    # a missing run (an empty cell) is fine: the other cells carry the group
    d = bootstrap_difference(a[:3], a, seeds_a=seeds[:3], sources_a=sources[:3])
    assert np.isfinite(d["diff_ci"]).all() and d["a"]["runs"] == 3
