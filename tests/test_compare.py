"""``pved compare``: two groups of transfer runs made outside a protocol."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.compare import compare_runs, find_transfer_runs, format_comparison
from pved.errors import PvedError

STEPS = [0, 250, 500, 750, 1000]


def make_run(
    root: Path,
    seed: int,
    curve: list[float],
    final: float,
    *,
    pair: str = "jaco-fetch",
    total_steps: int = 1000,
    stage: str = "transfer",
    steps: list[int] | None = None,
    bank: str | None = None,
) -> Path:
    """A finished run directory as `pved transfer` leaves it (the files compare reads);
    ``bank``: the source bank a shaped method's run recorded."""
    run_dir = root / f"seed{seed}"
    run_dir.mkdir(parents=True)
    config: dict[str, object] = {
        "stage": stage,
        "pair": pair,
        "ppo": {"seed": seed, "total_steps": total_steps},
    }
    if bank is not None:
        config["bank"] = bank
    (run_dir / "config.json").write_text(json.dumps({"config": config}))
    (run_dir / "result.json").write_text(json.dumps({"final/success_rate": final}))
    lines = [
        json.dumps({"step": s, "eval/success_rate": v})
        for s, v in zip(steps or STEPS, curve, strict=True)
    ]
    (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    return run_dir


def test_scores_and_steps_match_a_hand_computation(tmp_path: Path) -> None:
    a = [
        make_run(tmp_path / "a", 1, [0.0, 0.6, 1.0, 0.8, 0.9], 1.0),
        make_run(tmp_path / "a", 2, [0.0, 0.2, 0.4, 1.0, 1.0], 0.5),
    ]
    b = [
        make_run(tmp_path / "b", 1, [0.0, 0.0, 0.2, 0.4, 0.5], 0.25),
        make_run(tmp_path / "b", 2, [0.0, 0.0, 0.0, 0.2, 0.3], 0.25),
    ]
    result = compare_runs(a, b, ("new", "old"))
    assert result["pair"] == "jaco-fetch" and result["metric"] == "success_rate"
    groups = result["groups"]
    assert groups["new"]["final"]["mean"] == pytest.approx(0.75)
    assert result["diff"]["final"]["diff"] == pytest.approx(0.5)
    # early: the points at steps <= 250 (25% of 1000); drop: best point minus the last
    assert groups["new"]["early_mean"] == pytest.approx((0.3 + 0.1) / 2)
    assert groups["new"]["drop_mean"] == pytest.approx((0.1 + 0.0) / 2)
    assert result["diff"]["early"]["diff"] == pytest.approx(0.2)
    # old's mean curve ends at 0.4; new's mean passes it at step 250 (0.4), old's at 1000
    assert result["old_final"] == pytest.approx(0.4) and result["old_improved"]
    assert groups["new"]["steps_to_old_final"] == 250
    assert groups["old"]["steps_to_old_final"] == 1000
    table = format_comparison(result)
    assert "new − old = +0.500" in table and "| new | 2 | 0.750" in table


def test_runs_of_one_seed_are_drawn_together(tmp_path: Path) -> None:
    """Six runs in two seeds of three (one seed succeeds, one fails) leave the bootstrap
    two units to draw; as six independent seeds the interval of the mean is narrower."""
    flat = [0.0] * 5
    b = [make_run(tmp_path / "b", s, flat, 0.0) for s in (1, 2, 3)]
    clustered = [  # three runs of each seed (their curves tell them apart from copies)
        make_run(tmp_path / f"c{k}", seed, [0.01 * (k + 1), *flat[1:]], float(seed == 1))
        for k in range(3)
        for seed in (1, 2)
    ]
    apart = [make_run(tmp_path / "d", seed, flat, float(seed <= 3)) for seed in range(1, 7)]
    ci_clustered = compare_runs(clustered, b)["groups"]["A"]["final"]["mean_ci"]
    ci_apart = compare_runs(apart, b)["groups"]["A"]["final"]["mean_ci"]
    assert ci_clustered == [0.0, 1.0]
    assert 0.0 < ci_apart[0] and ci_apart[1] < 1.0


def test_source_banks_are_resampled_with_the_seeds(tmp_path: Path) -> None:
    """Three source banks, each over two seeds; the runs of bank 2 succeed, the others
    fail. By seed alone every resample's mean is 1/3; with the banks drawn too it is k/3
    for k draws of bank 2 among three, 0 in 8/27 and 1 in 1/27 of the resamples: the
    interval is [0, 1]. Where both groups ran with the same banks one draw serves both,
    and a difference that is 0.5 under every bank stays 0.5."""
    flat = [0.0] * 5
    banks = ["b0", "b1", "b2"]
    a = [
        make_run(tmp_path / f"a{k}", seed, flat, float(bank == "b2"), bank=bank)
        for k, bank in enumerate(banks)
        for seed in (1, 2)
    ]
    b = [make_run(tmp_path / "b", s, flat, 0.0) for s in (1, 2, 3)]
    result = compare_runs(a, b)
    assert result["groups"]["A"]["final"]["mean_ci"] == pytest.approx([0.0, 1.0])
    # a group's interval is its own, whatever it is compared with: these runs as B
    # (their draws made after the other group's) print the interval they print as A
    values = np.random.default_rng(0).uniform(size=8)  # many distinct resampled means
    c = [make_run(tmp_path / "c", s, flat, float(v)) for s, v in enumerate(values)]
    as_b = compare_runs(a, c, ("A", "C"))["groups"]["C"]["final"]
    assert as_b == compare_runs(c, b, ("C", "B"))["groups"]["C"]["final"]
    assert result["groups"]["A"]["sources"] == ["b0", "b0", "b1", "b1", "b2", "b2"]
    assert result["groups"]["B"]["sources"] is None
    lo, hi = result["diff"]["final"]["diff_ci"]
    assert lo <= 0 < hi and result["diff"]["final"]["p"] > 0.5
    assert "two-level bootstrap over source banks" in format_comparison(result)
    # both groups with the same banks: one draw
    c = [
        make_run(tmp_path / f"c{k}", seed, flat, float(bank == "b2") + 0.5, bank=bank)
        for k, bank in enumerate(banks)
        for seed in (1, 2)
    ]
    shared = compare_runs(c, a)
    assert shared["diff"]["final"]["diff_ci"] == pytest.approx([0.5, 0.5])
    assert "one draw of the source banks for both groups" in format_comparison(shared)
    # a group of shaped and plain runs is not one method
    with pytest.raises(PvedError, match="mixes runs with a source bank"):
        compare_runs([*a, make_run(tmp_path / "p", 9, flat, 0.0)], b)


def test_a_folder_is_searched_for_transfer_runs(tmp_path: Path) -> None:
    make_run(tmp_path / "x" / "transfer" / "pved", 1, [0.0] * 5, 1.0)
    make_run(tmp_path / "x" / "transfer" / "pved", 2, [0.0] * 5, 1.0)
    make_run(tmp_path / "x" / "model" / "pved", 0, [0.0] * 5, 1.0, stage="model")
    found = find_transfer_runs([tmp_path / "x"])
    assert [d.name for d in found] == ["seed1", "seed2"]
    with pytest.raises(PvedError, match="not a transfer run"):
        find_transfer_runs([tmp_path / "x" / "model" / "pved" / "seed0"])


def test_a_baseline_that_learned_nothing_gives_no_step_counts(tmp_path: Path) -> None:
    a = [make_run(tmp_path / "a", 1, [0.0, 0.5, 1.0, 1.0, 1.0], 1.0)]
    b = [make_run(tmp_path / "b", 1, [0.2, 0.1, 0.0, 0.0, 0.0], 0.0)]
    result = compare_runs(a, b)
    assert result["B_improved"] is False
    assert result["groups"]["A"]["steps_to_B_final"] is None
    assert "(B did not improve)" in format_comparison(result)


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("other_pair", "compare runs of one pair"),
        ("other_length", "compare runs of one length"),
        ("unfinished", "not finished"),
        ("missing", "no such file or directory"),
        ("twice", "is in both groups"),
        ("nan", "no finite final/success_rate"),
        ("schedule", "one evaluation schedule"),
        ("schedule_within", "is evaluated at other steps than"),
        ("foreign", "is not readable JSON"),
        ("empty", "no finished transfer run"),
    ],
)
def test_bad_input_is_one_line_error_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], setup: str, message: str
) -> None:
    curve = [0.0, 0.5, 1.0, 1.0, 1.0]
    a = [make_run(tmp_path / "a", s, curve, 1.0) for s in (1, 2)]
    b_dir = tmp_path / "b"
    kwargs: dict[str, object] = {}
    if setup == "other_pair":
        kwargs["pair"] = "reacher"
    elif setup == "other_length":
        kwargs["total_steps"] = 2000
    elif setup == "schedule":
        kwargs["steps"] = [0, 200, 400, 600, 1000]
    elif setup == "schedule_within":
        a.append(make_run(tmp_path / "a", 3, curve, 1.0, steps=[0, 200, 400, 600, 1000]))
    b_run = make_run(b_dir, 9, curve, 0.5, **kwargs)  # type: ignore[arg-type]
    b_args: list[Path] = [b_run]
    if setup == "unfinished":
        (b_run / "result.json").unlink()
    elif setup == "missing":
        b_args = [tmp_path / "nowhere"]
    elif setup == "twice":
        b_args = [a[0]]
    elif setup == "nan":
        (b_run / "result.json").write_text('{"final/success_rate": NaN}')
    elif setup == "foreign":
        (b_run / "config.json").write_text("not json at all")
    elif setup == "empty":
        (tmp_path / "empty").mkdir()
        b_args = [tmp_path / "empty"]
    out = tmp_path / "cmp.json"
    code, stdout, err = run_cli(capsys, "compare", "--a", *a, "--b", *b_args, "--json", out)
    assert code == 2 and stdout == ""
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_prints_the_table_and_writes_the_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for s in (1, 2):
        make_run(tmp_path / "a", s, [0.0, 0.5, 1.0, 1.0, 1.0], 1.0)
    b = [make_run(tmp_path / "b", s, [0.0, 0.0, 0.5, 0.5, 0.5], 0.5) for s in (1, 2)]
    out = tmp_path / "cmp.json"
    code, stdout, _ = run_cli(
        capsys,
        "compare",
        "--a",
        tmp_path / "a",
        "--b",
        *b,
        "--names",
        "log1p",
        "eq10",
        "--json",
        out,
    )
    assert code == 0
    assert "final: log1p − eq10 = +0.500" in stdout
    written = json.loads(out.read_text())
    assert np.isclose(written["diff"]["final"]["diff"], 0.5)
    assert written["groups"]["eq10"]["seeds"] == [1, 2]


def test_pooled_runs_count_a_copied_run_once_and_never_in_both_groups(tmp_path: Path) -> None:
    """Pooling PPO's runs of several protocol directories (issue 64's "pooled PPO-algorithm
    runs"): a run one directory copied from another is one run, counted once."""
    curve = [0.0, 0.2, 0.4, 0.6, 0.8]
    for seed in (1, 2, 3):
        make_run(tmp_path / "new", seed, curve, 1.0)
        make_run(tmp_path / "ppo", seed, curve, 0.2 * seed)
    for seed in (1, 2):  # another protocol's copies of two of them, and one run of its own
        copy = make_run(tmp_path / "other", seed, curve, 0.2 * seed)
        # a copy's result names its own files, and a restored one where it came from
        result = json.loads((copy / "result.json").read_text())
        result.update(policy=str(copy / "policy.pt"), restored_from="archive/x")
        (copy / "result.json").write_text(json.dumps(result))
    make_run(tmp_path / "other", 4, curve, 0.5)
    result = compare_runs([tmp_path / "new"], [tmp_path / "ppo", tmp_path / "other"])
    pooled = result["groups"]["B"]
    assert pooled["runs"] == 4 and pooled["copies"] == 2 and pooled["seeds"] == [1, 2, 3, 4]
    assert pooled["final"]["mean"] == pytest.approx((0.2 + 0.4 + 0.6 + 0.5) / 4)
    assert "counted once (B: 2)" in format_comparison(result)
    with pytest.raises(PvedError, match="are one run, in both groups"):
        compare_runs([tmp_path / "ppo"], [tmp_path / "other"])
