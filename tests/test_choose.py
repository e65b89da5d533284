"""Issue 64's rule (``pved choose``): rules 1-4 on screens built to tell each rule apart,
and the pre-registration file it writes read back by the protocol's own checks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import CURVE_STEPS, protocol_dir
from pved.analysis.judge import FOUR
from pved.errors import PvedError
from pved.protocol.choose import (
    choose,
    pinned_settings,
    preregistration_text,
    write_preregistration,
)
from pved.protocol.plan import ProtocolPlan
from pved.protocol.preregistration import (
    _check_design,
    _check_run_config,
    code_commit,
    read_file,
)

PPO = np.linspace(0.0, 0.5, len(CURVE_STEPS))
#: Each screen's selection, different on every pair, so a file that wrote one pair's
#: choice for another's would be caught.
BETA = dict(zip(FOUR, (0.01, 0.1, 1.0, 3.0), strict=True))
INIT = dict(zip(FOUR, (0, 1, 2, 1), strict=True))


def runs(offset: np.ndarray | float, n: int = 6) -> list[list[float]]:
    """``n`` runs of PPO's curve plus ``offset`` (a number or a curve), each moved a
    little (±0.005), so every interval is narrow."""
    return [list(PPO + offset + o) for o in np.linspace(-0.005, 0.005, n)]


def screen(
    root: Path, pair: str, methods: dict[str, list[list[float]]], budget: str = "screen-auc"
) -> Path:
    """A finished protocol directory of one pair whose runs have these curves; each
    candidate's selection: :data:`BETA` and :data:`INIT` of the pair (``pved-align``: ten
    times the β)."""
    marks = {
        "pved-prior": {"beta": BETA[pair], "init": INIT[pair]},
        "pved-align": {"beta": 10 * BETA[pair], "init": INIT[pair]},
    }
    return protocol_dir(root, {pair: methods}, budget, **marks)


def screens(
    root: Path, prior: dict[str, Any], align: dict[str, Any], aa: dict[str, float]
) -> list[Path]:
    """One screen per pair: the candidates' offsets from PPO, ppo-aa PPO plus ``aa``."""
    return [
        screen(
            root / pair,
            pair,
            {
                "ppo": runs(0.0),
                "ppo-aa": runs(aa[pair]),
                "pved-prior": runs(prior[pair]),
                "pved-align": runs(align[pair]),
            },
        )
        for pair in FOUR
    ]


def late_drop(early: float, last: float) -> np.ndarray:
    """Ahead by ``early`` at every point but the last, which is ``last`` from PPO's."""
    curve = np.full(len(CURVE_STEPS), early)
    curve[-1] = last
    return curve


def test_a_candidate_behind_in_final_anywhere_is_out_however_far_ahead_in_area(
    tmp_path: Path,
) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    # align ahead in area everywhere, but its final behind PPO's on jaco-fetch; prior
    # ahead on two pairs only and level elsewhere
    align = dict.fromkeys(FOUR, 0.2) | {"jaco-fetch": late_drop(0.3, -0.1)}
    prior = {p: (0.1 if p in FOUR[:2] else 0.0) for p in FOUR}
    c = choose(screens(tmp_path, prior, align, aa))
    assert c.out("pved-align") == ["jaco-fetch"] and c.ahead("pved-align") == 4
    assert c.out("pved-prior") == [] and c.ahead("pved-prior") == 2
    assert c.winner == "pved-prior" and "rule 3" in c.why


def test_a_tie_goes_to_the_larger_mean_difference_in_units_of_each_pairs_aa_noise(
    tmp_path: Path,
) -> None:
    # both ahead on all four; align's raw differences are larger (mean 0.23 against
    # 0.1), prior's are larger in A/A units: walker-hopper's A/A noise is 20x smaller
    aa = dict.fromkeys(FOUR, 0.2) | {"walker-hopper": 0.01}
    prior = dict.fromkeys(FOUR, 0.1)
    align = dict.fromkeys(FOUR, 0.3) | {"walker-hopper": 0.02}
    c = choose(screens(tmp_path, prior, align, aa))
    assert c.ahead("pved-prior") == c.ahead("pved-align") == 4
    assert c.tie_score("pved-prior") > c.tie_score("pved-align")
    assert c.winner == "pved-prior" and "rule 4" in c.why
    units = c.standings["pved-prior"]["walker-hopper"].area_units
    assert units == pytest.approx(0.1 / 0.015, rel=0.2)


def test_no_candidate_goes_before_every_pair_is_screened_and_nothing_is_registered(
    tmp_path: Path,
) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    dirs = screens(tmp_path, dict.fromkeys(FOUR, 0.2), dict.fromkeys(FOUR, 0.0), aa)
    c = choose(dirs[:3])
    assert c.winner is None and c.missing == (FOUR[3],) and "rule 1" in c.why
    with pytest.raises(PvedError, match="no method to pre-register"):
        preregistration_text(c, "paper", list(FOUR[:3]))
    # align ahead on the three pairs it was screened on, prior on the fourth alone: a
    # candidate not screened everywhere cannot go, however far ahead
    prior = dict.fromkeys(FOUR[:3], 0.0)
    dirs = screens(tmp_path / "b", prior | {FOUR[3]: 0.0}, dict.fromkeys(FOUR, 0.2), aa)
    only = screen(
        tmp_path / "x",
        FOUR[3],
        {"ppo": runs(0.0), "ppo-aa": runs(0.05), "pved-prior": runs(0.2)},
    )
    c = choose([*dirs[:3], only])
    assert c.ahead("pved-align") == 3 and c.ahead("pved-prior") == 1
    assert not c.screened_everywhere("pved-align") and c.winner == "pved-prior"


def test_when_every_candidate_is_behind_somewhere_all_stay_in(tmp_path: Path) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    behind = late_drop(0.3, -0.1)
    prior = dict.fromkeys(FOUR, 0.0) | {"reacher": behind}
    align = dict.fromkeys(FOUR, 0.2) | {"jaco-fetch": behind}
    c = choose(screens(tmp_path, prior, align, aa))
    assert c.out("pved-prior") == ["reacher"] and c.out("pved-align") == ["jaco-fetch"]
    assert c.winner == "pved-align" and "every candidate behind" in c.why


def test_screens_the_rule_does_not_read_are_refused(tmp_path: Path) -> None:
    old = screen(
        tmp_path / "a",
        "reacher",
        {"ppo": runs(0.0), "ppo-aa": runs(0.0), "pved-prior": runs(0.1)},
        budget="screen",
    )
    with pytest.raises(PvedError, match="'screen' protocol"):
        choose([old])
    no_aa = screen(tmp_path / "b", "reacher", {"ppo": runs(0.0), "pved-prior": runs(0.1)})
    with pytest.raises(PvedError, match="no ppo-aa runs"):
        choose([no_aa])
    paper = screen(
        tmp_path / "c", "reacher", {"ppo": runs(0.0), "ppo-aa": runs(0.0), "pved": runs(0.1)}
    )
    with pytest.raises(PvedError, match="beyond"):
        choose([paper])
    odd = screen(tmp_path / "d", "reacher", {"ppo": runs(0.0), "ppo-aa": runs(0.0)})
    summary = json.loads((odd / "summary.json").read_text())
    summary["pairs"]["reacher"]["methods"]["ppo"].update(runs_planned=15, runs_finished=6)
    (odd / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(PvedError, match="6 of 15 runs"):
        choose([odd])
    summary["pairs"] = {"my-arm": summary["pairs"]["reacher"]}
    summary["pairs"]["my-arm"]["methods"]["ppo"].update(runs_finished=15)
    (odd / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(PvedError, match="my-arm is not one of the rule's pairs"):
        choose([odd])


def test_the_file_registers_each_screens_choice_and_the_protocol_reads_it_back(
    tmp_path: Path,
) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    dirs = screens(tmp_path / "s", dict.fromkeys(FOUR, 0.2), dict.fromkeys(FOUR, 0.0), aa)
    c = choose(dirs)
    assert c.winner == "pved-prior"
    path = write_preregistration(
        c, tmp_path / "prior.toml", "paper-wide", ["reacher", "jaco-fetch"]
    )
    data = read_file(path)
    _check_design(path, data, ["reacher", "jaco-fetch"], "paper-wide")  # raises if not
    assert data["method"] == "pved-prior" and data["tuning_budget"] == "screen-auc"
    assert data["evaluation_seeds"] == 27 and data["source_policies"] == 3
    # the commit of the code that wrote it, which the gate compares the guide's code with
    assert data["code_commit"] == code_commit() and len(data["code_commit"]) == 40
    for pair in ("reacher", "jaco-fetch"):
        assert (data["pairs"][pair]["beta"], data["pairs"][pair]["init"]) == (
            BETA[pair],
            INIT[pair],
        )
    assert set(data["pairs"]) == {"reacher", "jaco-fetch"}
    # the settings this code gives the evaluation runs, which the gate checks, and the
    # code the screen runs were made by (these record none)
    screened = {"protocol": "s", "budget": "screen-auc", "tuning_seeds": [1]}
    fixed = {p: {"pved-prior": {**data["pairs"][p], **screened}} for p in data["pairs"]}
    plan = ProtocolPlan(list(fixed), ["pved-prior"], "paper-wide", tmp_path / "o", fixed)
    _check_run_config(path, data, plan, "pved-prior")  # raises if not
    assert data["pairs"]["reacher"]["run_config"]["shaping_form"] == "prior"
    assert "guide_limits" in data["pairs"]["jaco-fetch"]["run_config"]
    assert data["pairs"]["reacher"]["screen_fingerprints"] == {"unknown": 6}
    with pytest.raises(PvedError, match="never overwritten"):
        write_preregistration(c, path, "paper", ["reacher"])
    with pytest.raises(PvedError, match="paper's budgets"):
        preregistration_text(c, "screen", ["reacher"])


def test_the_cli_refuses_a_bad_budget_before_judging_and_writes_nothing(tmp_path: Path) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    dirs = screens(tmp_path / "s", dict.fromkeys(FOUR, 0.2), dict.fromkeys(FOUR, 0.0), aa)
    target = tmp_path / "p.toml"
    cmd = [sys.executable, "-m", "pved", "choose", *map(str, dirs), "--write", str(target)]
    bad = subprocess.run([*cmd, "--budget", "quick"], capture_output=True, text=True)
    assert bad.returncode == 2 and "paper's budgets" in bad.stderr and bad.stdout == ""
    assert len(bad.stderr.strip().splitlines()) == 1 and not target.exists()
    good = subprocess.run([*cmd, "--budget", "paper"], capture_output=True, text=True)
    assert good.returncode == 0, good.stderr
    assert "`pved-prior` goes to the paper's budget" in good.stdout and target.is_file()
    assert set(read_file(target)["pairs"]) == set(FOUR)


def test_the_file_says_where_the_code_gives_other_settings_than_the_screens_ran_under(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    aa = dict.fromkeys(FOUR, 0.05)
    dirs = screens(tmp_path / "s", dict.fromkeys(FOUR, 0.2), dict.fromkeys(FOUR, 0.0), aa)
    c = choose(dirs)
    now = pinned_settings(c, "paper", list(FOUR)).run_config
    # every screen run records this code's settings under fingerprint "f1", but
    # walker-hopper's were made before a fix to the guide's limits
    for directory, pair in zip(dirs, FOUR, strict=True):
        # a transfer run's config: its model's config is the model run's
        settings = {k: v for k, v in now[pair].items() if k != "model_config"}
        settings = json.loads(json.dumps(settings))
        if pair == "walker-hopper":
            settings["guide_limits"]["grad_ratio"] = 99.0
        for run in (directory / "runs" / pair / "transfer").glob("*/seed*"):
            config = {"stage": "transfer", "pair": pair, "method": run.parent.name, **settings}
            record = {"config": config, "fingerprint": "f1"}
            (run / "config.json").write_text(json.dumps(record))
    pinned = pinned_settings(c, "paper", list(FOUR))  # the records are read now
    assert pinned.drift == {"walker-hopper": ["guide_limits.grad_ratio"]}
    assert pinned.fingerprints == {pair: {"f1": 6} for pair in FOUR}
    path = write_preregistration(c, tmp_path / "p.toml", "paper", list(FOUR))
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "pved choose: pved-prior's settings in this code differ from those its screens ran "
        "under (walker-hopper: guide_limits.grad_ratio); the file pins this code's"
    ]
    data = read_file(path)
    assert data["pairs"]["walker-hopper"]["run_config"] == now["walker-hopper"]
    assert data["pairs"]["reacher"]["screen_fingerprints"] == {"f1": 6}
    assert "# pved-prior's settings in this code differ" in path.read_text()


ROOT = Path(__file__).resolve().parents[1]
#: Issue 64's four screens as committed, and the pre-registrations written from them.
COMMITTED_SCREENS = (
    "reacher-screen-auc-bar",
    "jaco-fetch-screen-auc",
    "walker-hopper-screen-auc-gate",
    "humanoid-ant-screen-auc",
)
COMMITTED_FILES = {
    "pved-align-paper-45.toml": ("paper-45", ["reacher", "jaco-fetch"]),
    "pved-align-paper.toml": ("paper", ["walker-hopper", "humanoid-ant"]),
}


@pytest.mark.slow  # the rule over four real screens (~10 s of bootstrap)
def test_the_committed_preregistrations_are_the_rules_choice_on_the_committed_screens() -> None:
    """The files the paper-budget runs read name the method, β and init that the rule
    finds in the committed screens now: a screen record or the rule changed after the
    files were written shows here."""
    c = choose([ROOT / "docs" / "protocol" / d for d in COMMITTED_SCREENS])
    assert c.winner == "pved-align", c.why
    for name, (budget, pairs) in COMMITTED_FILES.items():
        path = ROOT / "docs" / "preregistration" / name
        data = read_file(path)
        _check_design(path, data, pairs, budget)  # raises if not
        assert data["method"] == c.winner and data["budget"] == budget
        assert sorted(data["pairs"]) == sorted(pairs)
        for pair in pairs:
            s = c.standings[c.winner][pair]
            registered = data["pairs"][pair]
            assert (registered["beta"], registered["init"]) == (s.beta, s.init), pair
            assert registered["screen"] == s.record
