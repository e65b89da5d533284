"""``pved claims``: verdicts on the paper's seven claims from synthetic protocol outputs
whose scores are drawn so that the expected verdicts are known."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.claims import (
    FOUR,
    HOLDS,
    NOT_HOLD,
    UNDECIDED,
    combine,
    drop,
    early_score,
    eval_curve,
    judge_claims,
    write_claims,
)
from pved.analysis.curves import bootstrap_difference
from pved.errors import PvedError

STEPS = [0, 1000, 2000, 3000, 4000]  # early score: the points at steps <= 1000


def flat(final: float, spread: float = 0.02, n: int = 5) -> list[list[float]]:
    """``n`` runs whose curves rise linearly to ``final`` + small per-run offsets."""
    offsets = np.linspace(-spread, spread, n)
    return [list(np.linspace(0.0, final + o, len(STEPS))) for o in offsets]


def make_protocol(
    root: Path,
    pairs: dict[str, dict[str, list[list[float]]]],
    budget: str = "quick",
    metric: str = "success_rate",
    moved: bool = False,
) -> Path:
    """A protocol directory: summary.json and, per run, a metrics.jsonl with the run's
    evaluation curve at STEPS (its final score is the curve's last value). ``moved``:
    the summary's result paths point elsewhere (the directory was moved after the run)."""
    root.mkdir(parents=True)
    summary: dict[str, Any] = {"budget": budget, "pairs": {}}
    for pair, methods in pairs.items():
        entry: dict[str, Any] = {"metric": metric, "methods": {}}
        for method, curves in methods.items():
            runs = []
            for i, curve in enumerate(curves):
                key = f"{pair}/transfer/{method}/seed{i}"
                run_dir = root / "runs" / key
                run_dir.mkdir(parents=True)
                lines = [json.dumps({"step": s, "loss/loss": 1.0}) for s in STEPS]
                lines += [
                    json.dumps({"step": s, f"eval/{metric}": v})
                    for s, v in zip(STEPS, curve, strict=True)
                ]
                (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")
                result = (Path("/nonexistent") / key if moved else run_dir) / "result.json"
                runs.append({"key": key, "seed": i, metric: curve[-1], "result": str(result)})
            entry["methods"][method] = {
                "runs_planned": len(curves),
                "runs_finished": len(curves),
                "runs": runs,
                "ppo_final": 0.1,
                "steps_to_ppo_final": 2000 if method != "ppo" else 4000,
            }
        summary["pairs"][pair] = entry
    (root / "summary.json").write_text(json.dumps(summary))
    return root


def part(result: dict[str, Any], claim: int, text: str, pair: str) -> dict[str, Any]:
    (found,) = [
        p for p in result["claims"][claim - 1]["parts"] if p["part"] == text and p["pair"] == pair
    ]
    return found


def test_bootstrap_difference_of_two_independent_groups() -> None:
    a, b = np.array([0.5, 0.6, 0.7, 0.8]), np.array([0.1, 0.2, 0.1])
    state = np.random.get_state()  # noqa: NPY002
    d = bootstrap_difference(a, b, reps=500, seed=3)
    assert np.array_equal(np.random.get_state()[1], state[1])  # noqa: NPY002
    assert d == bootstrap_difference(a, b, reps=500, seed=3)  # reproducible
    np.testing.assert_allclose(d["diff"], a.mean() - b.mean())
    assert d["a"]["runs"] == 4 and d["b"]["runs"] == 3
    np.testing.assert_allclose([d["a"]["mean"], d["b"]["mean"]], [a.mean(), b.mean()])
    lo, hi = d["diff_ci"]
    assert 0 < lo < d["diff"] < hi  # clearly separated groups
    for g, x in (("a", a), ("b", b)):
        assert x.min() <= d[g]["mean_ci"][0] <= d[g]["mean"] <= d[g]["mean_ci"][1] <= x.max()
    same = bootstrap_difference(a, a.copy())
    assert same["diff"] == 0 and same["diff_ci"][0] < 0 < same["diff_ci"][1]
    with pytest.raises(PvedError):
        bootstrap_difference(a, np.array([]))
    with pytest.raises(PvedError):
        bootstrap_difference(a, np.array([0.1, np.nan]))
    with pytest.raises(PvedError):
        bootstrap_difference(a, b, reps=0)


def test_runs_that_share_a_seed_are_drawn_together() -> None:
    """Five seeds run with three source policies each, the source changing nothing: the
    15 runs hold the evidence of 5, and the interval must say so."""
    per_seed = np.array([1.0, 0.0, 0.0, 1.0, 0.0])
    a, seeds = np.repeat(per_seed, 3), np.repeat([20000, 40000, 60000, 80000, 100000], 3)
    b = np.zeros(15)
    runs = bootstrap_difference(a, b, reps=4000, seed=1)
    clustered = bootstrap_difference(a, b, reps=4000, seed=1, clusters_a=list(seeds))
    five = bootstrap_difference(per_seed, b, reps=4000, seed=1)
    assert clustered["diff"] == runs["diff"] == five["diff"]
    width = {k: d["diff_ci"][1] - d["diff_ci"][0] for k, d in
             (("runs", runs), ("clustered", clustered), ("five", five))}  # fmt: skip
    assert width["clustered"] > 1.3 * width["runs"]  # sqrt(3) in the limit
    assert abs(width["clustered"] - width["five"]) < 0.1
    # one label per run is the run bootstrap, to the last digit
    singletons = bootstrap_difference(a, b, reps=500, seed=2, clusters_a=list(range(15)))
    assert singletons == bootstrap_difference(a, b, reps=500, seed=2)
    with pytest.raises(PvedError, match="cluster labels"):
        bootstrap_difference(a, b, clusters_a=[1, 2])


def test_combination_rule() -> None:
    assert combine([HOLDS, HOLDS]) == HOLDS
    assert combine([HOLDS, UNDECIDED]) == UNDECIDED
    assert combine([HOLDS, UNDECIDED, NOT_HOLD]) == NOT_HOLD
    assert combine([]) == UNDECIDED


@pytest.fixture(scope="module")
def one_pair(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Every verdict kind on reacher and humanoid-ant (5 runs a method)."""
    root = tmp_path_factory.mktemp("claims") / "proto"
    make_protocol(
        root,
        {
            "reacher": {
                "pved": flat(0.9),
                "ppo": flat(0.5),  # still learns: well above 10% of the oracle's 1.0
                "oracle": flat(1.0, spread=0.0),
                "gupta2017": flat(0.9),  # identical to pved: undecided
                "pved-vae": flat(0.95),  # above pved: "pved beats pved-vae" does not hold
                "pved-state-only": flat(0.3),
                "pved-shared-only": flat(0.2, n=1),  # one run: needs >= 2
            },
            "humanoid-ant": {
                "pved": flat(0.8),
                "pved-vae": flat(0.8),  # similar to pved
                "ppo": flat(0.4),
                "pved-state-only": flat(0.4),  # does not beat ppo
                "pved-det-shared": flat(0.6),  # beats ppo: "does not beat" does not hold
            },
        },
    )
    return judge_claims([root])


@pytest.mark.parametrize(
    ("claim", "text", "pair", "verdict"),
    [
        (1, "pved beats ppo", "reacher", HOLDS),
        (2, "pved beats gupta2017", "reacher", UNDECIDED),
        (7, "pved beats pved-vae", "reacher", NOT_HOLD),
        (1, "ppo still learns", "reacher", HOLDS),
        (7, "pved similar to pved-vae", "humanoid-ant", HOLDS),
        (3, "pved-vae beats ppo", "humanoid-ant", HOLDS),
        (3, "pved-state-only does not beat ppo", "humanoid-ant", HOLDS),
        (3, "pved-det-shared does not beat ppo", "humanoid-ant", NOT_HOLD),
        (4, "pved beats pved-state-only", "reacher", HOLDS),
    ],
)
def test_each_verdict_kind(
    one_pair: dict[str, Any], claim: int, text: str, pair: str, verdict: str
) -> None:
    p = part(one_pair, claim, text, pair)
    assert p["verdict"] == verdict, p
    assert (p["reason"] is None) == (verdict != UNDECIDED)


def test_numbers_of_a_beats_part(one_pair: dict[str, Any]) -> None:
    p = part(one_pair, 1, "pved beats ppo", "reacher")
    pved, ppo = p["groups"]
    assert (pved["method"], pved["runs"], ppo["method"]) == ("pved", 5, "ppo")
    np.testing.assert_allclose([pved["mean"], ppo["mean"]], [0.9, 0.5])
    np.testing.assert_allclose(p["difference"]["value"], 0.4)
    lo, hi = p["difference"]["ci"]
    assert 0 < lo < 0.4 < hi
    assert p["steps_to_ppo_final"] == {"pved": 2000, "ppo": 4000}
    assert one_pair["pairs"]["reacher"]["runs"]["pved"] == 5


def test_separated_groups_are_not_similar(tmp_path: Path) -> None:
    root = make_protocol(
        tmp_path / "p", {"humanoid-ant": {"pved": flat(0.8), "pved-vae": flat(0.3)}}
    )
    assert (
        part(judge_claims([root]), 7, "pved similar to pved-vae", "humanoid-ant")["verdict"]
        == NOT_HOLD
    )


def test_equal_constant_groups_of_different_sizes_are_not_separated(tmp_path: Path) -> None:
    # mean([0.1] * 3) and mean([0.1] * 5) differ by rounding (1e-17): no difference
    root = make_protocol(
        tmp_path / "p",
        {"humanoid-ant": {"pved": flat(0.1, 0.0, n=3), "pved-vae": flat(0.1, 0.0, n=5)}},
    )
    result = judge_claims([root])
    assert part(result, 7, "pved similar to pved-vae", "humanoid-ant")["verdict"] == HOLDS
    assert part(result, 3, "pved beats ppo", "humanoid-ant")["verdict"] == UNDECIDED


def test_ppo_against_the_oracle(tmp_path: Path) -> None:
    root = make_protocol(
        tmp_path / "p",
        {
            "jaco-fetch": {"ppo": flat(0.0, spread=0.01), "oracle": flat(1.0, spread=0.0)},
            "walker-hopper": {"ppo": flat(0.6), "oracle": flat(1.0)},  # learns: not a failure
            "reacher": {"ppo": flat(0.1, spread=0.1), "oracle": flat(1.0)},  # CI holds the bar
        },
    )
    result = judge_claims([root])
    fails = part(result, 1, "ppo fails completely", "jaco-fetch")
    assert fails["verdict"] == HOLDS
    np.testing.assert_allclose(fails["bar"], 0.1)
    assert part(result, 1, "ppo fails completely", "walker-hopper")["verdict"] == NOT_HOLD
    learns = part(result, 1, "ppo still learns", "reacher")
    assert learns["verdict"] == UNDECIDED and "bar" in learns["reason"]


def test_missing_methods_and_too_few_runs_are_undecided(one_pair: dict[str, Any]) -> None:
    missing = part(one_pair, 2, "pved beats gupta2017", "walker-hopper")  # no such pair
    assert missing["verdict"] == UNDECIDED
    assert missing["reason"] == "no runs of pved on walker-hopper"
    no_oracle = part(one_pair, 1, "ppo fails completely", "jaco-fetch")
    assert no_oracle["verdict"] == UNDECIDED and "no runs of ppo" in no_oracle["reason"]
    gupta = part(one_pair, 3, "gupta2017 does not beat ppo", "humanoid-ant")
    assert gupta["reason"] == "no runs of gupta2017 on humanoid-ant"
    few = part(one_pair, 5, "pved beats pved-shared-only", "reacher")
    assert few["verdict"] == UNDECIDED and "needs >= 2 runs" in few["reason"]
    # claims combine their parts: an undecided part leaves claim 2 undecided, a part that
    # does not hold makes claim 7 not hold
    verdicts = {c["claim"]: c["verdict"] for c in one_pair["claims"]}
    assert verdicts[2] == UNDECIDED and verdicts[7] == NOT_HOLD


def test_claim_holds_when_every_pair_holds(tmp_path: Path) -> None:
    pairs = {p: {"pved": flat(0.9), "pved-shared-only": flat(0.2)} for p in FOUR}
    claims = judge_claims([make_protocol(tmp_path / "p", pairs)])["claims"]
    assert claims[4]["verdict"] == HOLDS
    assert [p["verdict"] for p in claims[4]["parts"]] == [HOLDS] * 4
    # one pair short of four: undecided, not holds
    del pairs["jaco-fetch"]
    claims = judge_claims([make_protocol(tmp_path / "q", pairs)])["claims"]
    assert claims[4]["verdict"] == UNDECIDED


def test_eval_curve_keeps_the_last_record_of_a_step(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    records = [  # an interrupted attempt (0, 1000), then the resumed one from step 0
        {"step": 0, "eval/success_rate": 0.1},
        {"step": 1000, "eval/success_rate": 0.9},
        {"step": 500, "loss/loss": 2.0},
        {"step": 0, "eval/success_rate": 0.2},
        {"step": 1000, "eval/success_rate": 0.4},
        {"step": 2000, "eval/success_rate": 0.8},
        {"step": 4000, "eval/success_rate": 0.5},
    ]
    path.write_text("\n".join(json.dumps(r) for r in records) + "\n")
    steps, values = eval_curve(path, "success_rate")
    assert steps.tolist() == [0, 1000, 2000, 4000]
    np.testing.assert_allclose(values, [0.2, 0.4, 0.8, 0.5])
    np.testing.assert_allclose(early_score(steps, values), 0.3)  # steps <= 1000
    np.testing.assert_allclose(drop(values), 0.3)  # best 0.8, last 0.5
    path.write_text('{"step": 0, "eval/success_rate": 0.1}\n{"step": 10, "eval/su\n')
    with pytest.raises(PvedError, match="unreadable metrics"):
        eval_curve(path, "success_rate")


def test_early_and_drop_from_metrics(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)

    def runs(curve: list[float]) -> list[list[float]]:
        return [list(np.asarray(curve) + rng.uniform(-0.01, 0.01, len(STEPS))) for _ in range(5)]

    fast_then_unstable = [0.0, 0.6, 0.9, 0.9, 0.5]  # early mean 0.3, drop 0.4
    slow_and_stable = [0.0, 0.0, 0.3, 0.6, 0.9]  # early mean 0.0, drop 0
    pairs = {
        "jaco-fetch": {"pved": runs(slow_and_stable), "pved-det-shared": runs(fast_then_unstable)}
    }
    # moved: the run directories are found under DIR/runs/KEY, not at the summary's paths
    result = judge_claims([make_protocol(tmp_path / "p", pairs, moved=True)])
    early = part(result, 6, "pved-det-shared faster early than pved", "jaco-fetch")
    assert early["verdict"] == HOLDS and early["score"] == "early"
    det, pved = early["groups"]
    assert det["method"] == "pved-det-shared"
    np.testing.assert_allclose([det["mean"], pved["mean"]], [0.3, 0.0], atol=0.011)
    stable = part(result, 6, "pved more stable than pved-det-shared", "jaco-fetch")
    assert stable["verdict"] == HOLDS and stable["score"] == "drop"
    np.testing.assert_allclose(stable["difference"]["value"], 0.4, atol=0.03)
    # the reverse rule on the same numbers: pved does not learn faster early
    reversed_pairs = {"jaco-fetch": {"pved": pairs["jaco-fetch"]["pved-det-shared"],
                                     "pved-det-shared": pairs["jaco-fetch"]["pved"]}}  # fmt: skip
    result = judge_claims([make_protocol(tmp_path / "q", reversed_pairs)])
    assert (
        part(result, 6, "pved-det-shared faster early than pved", "jaco-fetch")["verdict"]
        == NOT_HOLD
    )
    assert result["claims"][5]["verdict"] == NOT_HOLD


def test_cli_writes_claims_and_rejects_bad_dirs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = make_protocol(tmp_path / "a", {"reacher": {"pved": flat(0.9), "ppo": flat(0.5)}})
    b = make_protocol(tmp_path / "b", {"jaco-fetch": {"pved": flat(0.9)}}, budget="paper")
    out = tmp_path / "out"
    code, stdout, err = run_cli(capsys, "claims", a, b, "--out", out)
    assert code == 0, err
    assert "Claim 1: undecided" in stdout and str(out / "claims.md") in stdout
    result = json.loads((out / "claims.json").read_text())
    assert [c["claim"] for c in result["claims"]] == list(range(1, 8))
    assert {e["budget"] for e in result["inputs"]} == {"quick", "paper"}
    md = (out / "claims.md").read_text()
    assert md.count("## Claim ") == 7
    assert "budget **paper**" in md and "pved 5, ppo 5" in md
    assert "| pved beats ppo | reacher | **holds** |" in md
    # the matrix: one row per part, the four pairs in Fig. 3's order
    assert "| claim | part | reacher | walker-hopper | jaco-fetch | humanoid-ant |" in md
    row = next(line for line in md.splitlines() if line.startswith("| 1 | pved beats ppo |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "holds (0.400)" and cells[3] == cells[4] == cells[5] == "undecided"
    assert "| 3 | pved-vae beats ppo |  |  |  | undecided |" in md
    # default OUT: the first DIR
    assert write_claims([a]) == a / "claims.md" and (a / "claims.json").is_file()

    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "summary.json").write_text('{"pairs": ')
    for argv, words in (
        ([tmp_path / "empty"], "not a directory"),
        ([tmp_path], "no summary.json"),
        ([corrupt], "not JSON"),
        ([a, make_protocol(tmp_path / "c", {"reacher": {"ppo": flat(0.1)}})], "in both"),
        ([a, a], "given twice"),
    ):
        code, stdout, err = run_cli(capsys, "claims", *argv)
        assert code == 2 and stdout == ""
        assert err.startswith("pved: error: ") and words in err, err
        assert err.count("\n") == 1
