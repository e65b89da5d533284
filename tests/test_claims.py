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
    claims_markdown,
    combine,
    family_wise,
    judge_claims,
    write_claims,
)
from pved.analysis.curves import bootstrap_difference, bootstrap_mean
from pved.analysis.judge import (
    FOUR,
    HOLDS,
    NOT_HOLD,
    UNDECIDED,
    Judge,
    drop,
    early_score,
    eval_curve,
    load_pairs,
    not_beat_verdict,
    similar_verdict,
)
from pved.analysis.transfer_measures import holm, holm_adjusted
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
    sources: int = 0,
) -> Path:
    """A protocol directory: summary.json and, per run, a metrics.jsonl with the run's
    evaluation curve at STEPS (its final score is the curve's last value). ``moved``:
    the summary's result paths point elsewhere (the directory was moved after the run).
    ``sources`` > 0: the shaped methods' runs are named as a protocol names them, run i
    with source policy i % sources and seed 20000 (1 + i // sources) (plain PPO and the
    oracle keep a seed a run)."""
    root.mkdir(parents=True)
    summary: dict[str, Any] = {"budget": budget, "pairs": {}}
    for pair, methods in pairs.items():
        entry: dict[str, Any] = {"metric": metric, "methods": {}}
        for method, curves in methods.items():
            runs = []
            for i, curve in enumerate(curves):
                seed = i
                key = f"{pair}/transfer/{method}/seed{i}"
                if sources and method not in ("ppo", "oracle"):
                    seed = 20000 * (1 + i // sources)
                    key = f"{pair}/transfer/{method}-beta0.01-init0-src{i % sources}/seed{seed}"
                run_dir = root / "runs" / key
                run_dir.mkdir(parents=True)
                lines = [json.dumps({"step": s, "loss/loss": 1.0}) for s in STEPS]
                lines += [
                    json.dumps({"step": s, f"eval/{metric}": v})
                    for s, v in zip(STEPS, curve, strict=True)
                ]
                (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")
                result = (Path("/nonexistent") / key if moved else run_dir) / "result.json"
                runs.append({"key": key, "seed": seed, metric: curve[-1], "result": str(result)})
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
        lo_g, hi_g = d[g]["mean_ci"]
        # (a resample of equal values sums to them up to rounding)
        assert x.min() - 1e-12 <= lo_g <= d[g]["mean"] <= hi_g <= x.max() + 1e-12
    same = bootstrap_difference(a, a.copy(), labels=("a", "a again"))  # two groups: apart
    assert same["diff"] == 0 and same["diff_ci"][0] < 0 < same["diff_ci"][1]
    assert bootstrap_difference(a, a.copy())["diff_ci"] == [0.0, 0.0]  # no names: one group
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
    clustered = bootstrap_difference(a, b, reps=4000, seed=1, seeds_a=list(seeds))
    five = bootstrap_difference(per_seed, b, reps=4000, seed=1)
    assert clustered["diff"] == runs["diff"] == five["diff"]
    width = {k: d["diff_ci"][1] - d["diff_ci"][0] for k, d in
             (("runs", runs), ("clustered", clustered), ("five", five))}  # fmt: skip
    assert width["clustered"] > 1.3 * width["runs"]  # sqrt(3) in the limit
    assert abs(width["clustered"] - width["five"]) < 0.1
    # one label per run is the run bootstrap, to the last digit
    singletons = bootstrap_difference(a, b, reps=500, seed=2, seeds_a=list(range(15)))
    assert singletons == bootstrap_difference(a, b, reps=500, seed=2)
    with pytest.raises(PvedError, match="seed labels"):
        bootstrap_difference(a, b, seeds_a=[1, 2])


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
                "oracle": flat(1.0, spread=0.0),  # the margin: 0.1
                "pved": flat(0.8),
                "pved-vae": flat(0.8),  # similar to pved: the CI is inside ±0.1
                "ppo": flat(0.4),
                "pved-state-only": flat(0.4),  # does not beat ppo: the CI is below +0.1
                "pved-det-shared": flat(0.6),  # beats ppo by more than 0.1: does not hold
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
        tmp_path / "p",
        {"humanoid-ant": {"pved": flat(0.8), "pved-vae": flat(0.3), "oracle": flat(1.0)}},
    )
    assert (
        part(judge_claims([root]), 7, "pved similar to pved-vae", "humanoid-ant")["verdict"]
        == NOT_HOLD
    )


def test_equal_constant_groups_of_different_sizes_are_not_separated(tmp_path: Path) -> None:
    # mean([0.1] * 3) and mean([0.1] * 5) differ by rounding (1e-17): no difference
    root = make_protocol(
        tmp_path / "p",
        {
            "humanoid-ant": {
                "pved": flat(0.1, 0.0, n=3),
                "pved-vae": flat(0.1, 0.0, n=5),
                "oracle": flat(1.0),
            }
        },
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


# ---- source policies, equivalence margins and the family-wise view


def by_source(finals: list[float], seeds: int = 5) -> list[list[float]]:
    """Runs of a shaped method (make_protocol's ``sources``=len(finals)): run i ends at
    finals[i % len(finals)] plus a small per-seed offset."""
    k = len(finals)
    return [
        list(np.linspace(0.0, finals[i % k] + 0.001 * (i // k), len(STEPS)))
        for i in range(k * seeds)
    ]


def test_source_policies_are_resampled(tmp_path: Path) -> None:
    """PVED's three source policies end at 0.0, 0.1 and 1.0, each alike over its five
    seeds; PPO at 0.2. By seed alone PVED's mean (0.37) beats PPO surely; with the source
    policies drawn too, 30% of the resamples hold only the two weak ones: undecided."""
    pairs = {"reacher": {"pved": by_source([0.0, 0.1, 1.0]), "ppo": flat(0.2, 0.01, n=15)}}
    result = judge_claims([make_protocol(tmp_path / "p", pairs, sources=3)])
    beats = part(result, 1, "pved beats ppo", "reacher")
    assert beats["verdict"] == UNDECIDED, beats
    pved, ppo = beats["groups"]
    assert (pved["sources"], pved["seeds"], ppo["sources"], ppo["seeds"]) == (3, 5, 0, 15)
    lo, hi = beats["difference"]["ci"]
    assert lo < 0 < hi and beats["p"] > 0.5
    # the same runs with keys that name no source policy: drawn by seed alone, as the
    # intervals were before, the interval is narrow around 0.17 and the part holds
    root = make_protocol(tmp_path / "q", pairs, sources=3)
    summary = json.loads((root / "summary.json").read_text())
    for i, run in enumerate(summary["pairs"]["reacher"]["methods"]["pved"]["runs"]):
        run["key"] = f"reacher/transfer/pved/run{i}"
    (root / "summary.json").write_text(json.dumps(summary))
    by_seed = part(judge_claims([root]), 1, "pved beats ppo", "reacher")
    assert by_seed["verdict"] == HOLDS and by_seed["groups"][0]["sources"] == 0
    assert by_seed["difference"]["ci"][0] > 0.15


def test_a_method_carries_one_interval_in_every_part(tmp_path: Path) -> None:
    """PPO's runs print one interval wherever they appear: against PVED (drawn after
    PVED's source policies), against Gupta et al. and against the oracle's bar alike,
    and it is bootstrap_mean's; the reps and seed a Judge is given move it."""
    pairs = {
        "reacher": {
            "pved": by_source([0.0, 0.3, 0.9]),
            "gupta2017": by_source([0.2, 0.1, 0.5]),
            "ppo": [list(np.linspace(0.0, v, len(STEPS))) for v in [1, 0, 0, 0.04, 0] * 3],
            "oracle": flat(0.7, 0.1, n=15),
        }
    }
    root = make_protocol(tmp_path / "p", pairs, sources=3)
    result = judge_claims([root])
    ppo = [
        g["mean_ci"]
        for claim in result["claims"]
        for p in claim["parts"]
        if p["pair"] == "reacher" and p["score"] == "final"
        for g in p.get("groups", [])
        if g["method"] == "ppo"
    ]
    assert len(ppo) >= 2 and all(ci == ppo[0] for ci in ppo)
    finals = np.array([c[-1] for c in pairs["reacher"]["ppo"]])
    assert ppo[0] == bootstrap_mean(finals, list(range(15)), label=("reacher", "ppo"))["mean_ci"]
    judge = Judge(load_pairs([root]), reps=500, seed=7)
    other = judge.mean("reacher", "ppo")
    assert isinstance(other, dict) and other["mean_ci"] != ppo[0]


def test_margin_rules() -> None:
    """ "Similar": the whole CI inside (−m, +m); "does not beat": the CI below +m."""
    m = 0.1
    assert similar_verdict([-0.05, 0.08], m) == HOLDS
    assert similar_verdict([-0.3, 0.3], m) == UNDECIDED  # contains 0, wider than the margin
    assert similar_verdict([0.05, 0.3], m) == UNDECIDED
    assert similar_verdict([0.1, 0.3], m) == NOT_HOLD
    assert similar_verdict([-0.4, -0.1], m) == NOT_HOLD
    assert not_beat_verdict([-0.5, 0.09], m) == HOLDS
    assert not_beat_verdict([-0.3, 0.3], m) == UNDECIDED
    assert not_beat_verdict([0.1, 0.3], m) == NOT_HOLD


def test_a_wide_interval_that_contains_0_is_not_similarity(tmp_path: Path) -> None:
    """Runs spread from 0.1 to 0.9 around equal means: the CI of the difference holds 0
    but is far wider than the margin (10% of the oracle's 1.0): neither "similar" nor "does
    not beat" is shown (both held before, the CI containing 0). Tight groups are."""
    wide = flat(0.5, spread=0.4)
    pairs = {
        "humanoid-ant": {
            "oracle": flat(1.0, spread=0.0),
            "pved": wide,
            "pved-vae": flat(0.5, spread=0.4),
            "ppo": flat(0.5, spread=0.4),
            "pved-state-only": wide,
            "pved-det-shared": flat(0.5, spread=0.01),
            "gupta2017": flat(0.5, spread=0.01, n=6),
        }
    }
    result = judge_claims([make_protocol(tmp_path / "p", pairs)])
    similar = part(result, 7, "pved similar to pved-vae", "humanoid-ant")
    lo, hi = similar["difference"]["ci"]
    assert lo < -0.1 and 0.1 < hi
    assert similar["verdict"] == UNDECIDED and "±m" in similar["reason"]
    assert similar["margin"] == pytest.approx(0.1)
    state_only = part(result, 3, "pved-state-only does not beat ppo", "humanoid-ant")
    assert state_only["verdict"] == UNDECIDED and "+m" in state_only["reason"]
    # one wide group is enough: tight gupta2017 runs against the wide ppo ones
    tight = part(result, 3, "gupta2017 does not beat ppo", "humanoid-ant")
    assert tight["verdict"] == UNDECIDED
    # tight groups: the CI inside the margin
    det = judge_claims(
        [
            make_protocol(
                tmp_path / "q",
                {
                    "humanoid-ant": {
                        "oracle": flat(1.0),
                        "ppo": flat(0.5, 0.01),
                        "pved-det-shared": flat(0.52, 0.01),
                        "pved": flat(0.5, 0.01),
                        "pved-vae": flat(0.45, 0.01),
                    }
                },
            )
        ]
    )
    assert part(det, 3, "pved-det-shared does not beat ppo", "humanoid-ant")["verdict"] == HOLDS
    assert part(det, 7, "pved similar to pved-vae", "humanoid-ant")["verdict"] == HOLDS
    md = claims_markdown(det)
    row = next(r for r in md.splitlines() if r.startswith("| pved similar to pved-vae |"))
    assert "margin ±0.100 (10% of oracle's mean final 1.000)" in row
    # no oracle: no scale for the margin
    alone = judge_claims(
        [make_protocol(tmp_path / "r", {"humanoid-ant": {"pved": wide, "pved-vae": wide}})]
    )
    no_scale = part(alone, 7, "pved similar to pved-vae", "humanoid-ant")
    assert no_scale["verdict"] == UNDECIDED
    assert no_scale["reason"] == "no runs of oracle on humanoid-ant: no scale for the margin"


def test_holm_on_a_worked_example() -> None:
    """m = 4 at α = 0.05: sorted 0.005 <= 0.05/4, 0.01 <= 0.05/3, 0.03 > 0.05/2: stop."""
    p = [0.01, 0.04, 0.03, 0.005]
    assert holm(p, 0.05) == [True, False, False, True]
    # adjusted: 4 x 0.005, 3 x 0.01, 2 x 0.03, max(0.06, 1 x 0.04)
    assert holm_adjusted(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.04], 0.05) == [True] and holm([], 0.05) == []
    # Bonferroni would reject only the first; Holm steps down to the second as well
    assert holm([0.001, 0.02, 0.5], 0.05) == [True, True, False]


def test_family_wise_verdicts() -> None:
    """Holm over the distinct tests of a judgement: a verdict whose p does not survive
    becomes undecided in the family-wise column, a claim combines its parts'."""

    def p(name: str, pair: str, verdict: str, pvalue: float | None) -> dict[str, Any]:
        return {"part": name, "pair": pair, "verdict": verdict, "p": pvalue}

    claims = [
        {"parts": [p("a", "x", HOLDS, 0.001), p("b", "x", HOLDS, 0.02)]},
        {"parts": [p("a", "x", HOLDS, 0.001), p("c", "x", NOT_HOLD, 0.01)]},
        {"parts": [p("d", "x", UNDECIDED, 0.6), p("e", "x", UNDECIDED, None)]},
    ]
    family = family_wise(claims, alpha=0.05)
    # four distinct tests (a twice is one): 0.001 x 4, 0.01 x 3, 0.02 x 2, 0.6
    assert family == {"alpha": 0.05, "tests": 4, "parts": 6, "parts_tested": 5}
    parts = [part for claim in claims for part in claim["parts"]]
    assert [q["p_holm"] for q in parts] == pytest.approx([0.004, 0.04, 0.004, 0.03, 0.6, None])
    assert [q["family_verdict"] for q in parts] == [HOLDS, HOLDS, HOLDS, NOT_HOLD] + [UNDECIDED] * 2
    # one more test of p = 0.02 makes the family five: 0.02 x 3 = 0.06 > 0.05
    claims[2]["parts"].append(p("f", "x", HOLDS, 0.02))
    family_wise(claims, alpha=0.05)
    assert claims[0]["parts"][1]["family_verdict"] == UNDECIDED
    assert [c["family_verdict"] for c in claims] == [UNDECIDED, NOT_HOLD, UNDECIDED]


def test_claims_md_says_what_is_computed(one_pair: dict[str, Any]) -> None:
    md = claims_markdown(one_pair)
    assert "over seeds" not in md and "contains 0 (holds)" not in md
    assert "two-level bootstrap" in md and "source policies" in md
    family = one_pair["family"]
    assert f"over the {family['tests']} distinct tests of this judgement" in md
    assert "| claim | verdict per part | family-wise (Holm) |" in md
    assert all("family_verdict" in c for c in one_pair["claims"])
    assert "contains 0" not in one_pair["definitions"]["similar"]
