"""Pre-registration: a method beyond the paper is evaluated at the paper's budget only
with a committed file that fixed its choices first, or labelled exploratory."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from pved.errors import PvedError
from pved.protocol import preregistration
from pved.protocol.plan import ProtocolPlan
from pved.protocol.preregistration import (
    EXPLORATORY,
    PREREGISTERED,
    check_gate,
    evaluation_settings,
    gated_methods,
    mark_summary,
    write_record,
)
from pved.spec import toml_value

T0 = 1_767_225_600  # 2026-01-01T00:00:00Z: when the file is committed
ALIGN = ["pved-align", "ppo"]


def run_config(pair: str = "reacher", beta: float = 0.1, init: int = 2) -> dict[str, Any]:
    """The settings this code gives pved-align's paper evaluation runs on ``pair``."""
    chosen = {"beta": beta, "init": init, "protocol": "q", "budget": "quick", "tuning_seeds": [1]}
    plan = ProtocolPlan([pair], ALIGN, "paper", Path("unused"), {pair: {"pved-align": chosen}})
    return evaluation_settings(plan, pair, "pved-align")[0]


def table(values: dict[str, Any]) -> str:
    return "".join(f"{toml_value({k: v})[2:-2]}\n" for k, v in values.items())


REGISTERED = """\
method = "pved-align"
budget = "paper"
date = 2025-12-31
evaluation_seeds = 5
source_policies = 3
tuning_seeds = [2000, 4000, 6000]
tuning_budget = "quick"
code_commit = "CODE"
[settings]
model = "pved"
shaping_form = "align"
[pairs.reacher]
beta = 0.1
init = 2
[pairs.reacher.run_config]
""" + table(run_config())


def git(repo: Path, *args: str, when: int = T0) -> None:
    env = {
        **os.environ,
        "GIT_AUTHOR_DATE": f"@{when} +0000",
        "GIT_COMMITTER_DATE": f"@{when} +0000",
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@example.org",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@example.org",
    }
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, env=env)


@pytest.fixture
def registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A git repository whose docs/preregistration/align.toml is committed at T0, after
    the commit of the code it registers (src/pved/, the running code's checkout here)."""
    repo = tmp_path / "repo"
    (repo / "docs/preregistration").mkdir(parents=True)
    git(repo, "init", "-q")
    for folder in ("transfer", "rl", "models", "analysis"):
        (repo / "src/pved" / folder).mkdir(parents=True)
        (repo / "src/pved" / folder / "code.py").write_text("x = 1\n")
    git(repo, "add", "src")
    git(repo, "commit", "-q", "-m", "the guide's code", when=T0 - 60)
    monkeypatch.setattr(preregistration, "PACKAGE", repo / "src/pved")
    path = repo / "docs/preregistration/align.toml"
    path.write_text(REGISTERED.replace("CODE", preregistration.code_commit()))
    git(repo, "add", "docs/preregistration/align.toml")
    git(repo, "commit", "-q", "-m", "pre-register pved-align")
    return path


def gate(out: Path, files: list[Path], **kwargs: Any) -> Any:
    return check_gate(["reacher"], ALIGN, "paper", out, None, files, **kwargs)


def test_only_methods_beyond_the_paper_at_the_papers_budget_are_gated() -> None:
    every = ["pved", "pved-align", "pved-anneal", "gupta2017", "ppo", "ppo-aa", "oracle"]
    assert gated_methods(every, "paper") == ["pved-align", "pved-anneal"]
    assert gated_methods(every, "paper-wide") == ["pved-align", "pved-anneal"]
    assert gated_methods(every, "quick") == gated_methods(every, "smoke") == []
    # nothing to register: no error, no status
    assert check_gate(["reacher"], ["pved", "ppo", "ppo-aa"], "paper", Path("x"), None).status == {}


def test_without_a_file_the_protocol_refuses_unless_exploratory(tmp_path: Path) -> None:
    with pytest.raises(PvedError, match=r"pved-align is beyond the paper.*--preregistration"):
        gate(tmp_path / "out", [])
    assert not (tmp_path / "out").exists()
    status = gate(tmp_path / "out", [], exploratory=True).status
    assert status == {"pved-align": {"status": EXPLORATORY, "why": "no pre-registration given"}}


def test_a_committed_file_is_the_selection(tmp_path: Path, registered: Path) -> None:
    result = gate(tmp_path / "out", [registered])
    state = result.status["pved-align"]
    assert state["status"] == PREREGISTERED and state["committed"] == "2026-01-01T00:00:00Z"
    assert len(state["commit"]) == 40 and not os.path.isabs(state["file"])
    chosen = result.fixed["reacher"]["pved-align"]
    assert (chosen["beta"], chosen["init"], chosen["tuning_seeds"]) == (0.1, 2, [2000, 4000, 6000])
    # --selection-from's selection must be the file's
    screen = {"protocol": "q", "budget": "quick", "tuning_seeds": [2000], "candidates": []}
    same = {"reacher": {"pved-align": {"beta": 0.1, "init": 2, **screen}}}
    assert check_gate(["reacher"], ALIGN, "paper", tmp_path / "o", same, [registered]).fixed == same
    other = {"reacher": {"pved-align": {"beta": 1.0, "init": 2, **screen}}}
    with pytest.raises(
        PvedError, match=r"registered beta 0\.1 init 2, the selection used is beta 1 "
    ):
        check_gate(["reacher"], ALIGN, "paper", tmp_path / "o", other, [registered])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("untracked", "not tracked by git"),
        ("modified", "changed since its last commit"),
        ("staged", "changed since its last commit"),
        ('budget = "quick"', "budget 'quick', the protocol's is 'paper'"),
        ("evaluation_seeds = 27", "evaluation_seeds 27, the protocol's is 5"),
        ("tuning_seeds = [2000, 20000]", r"tuned on evaluation seeds \[20000\]"),
        (
            '[settings]\nshaping_form = "eq10"',
            "settings.shaping_form = 'eq10', but pved-align's is",
        ),
        ('method = "pved"', "pved is not a method beyond the paper"),
        ("[pairs.walker-hopper]", "no choice for reacher"),
        ("beta = 'x'", "pairs.reacher has no number 'beta'"),
    ],
)
def test_an_invalid_file_is_refused_in_one_line(
    tmp_path: Path, registered: Path, change: str, message: str
) -> None:
    repo = registered.parents[2]
    if change == "untracked":
        registered = registered.with_name("new.toml")
        registered.write_text(REGISTERED)
    elif change in ("modified", "staged"):
        registered.write_text(REGISTERED + "# later\n")
        if change == "staged":
            git(repo, "add", str(registered.relative_to(repo)))
    else:
        key = change.split(" ")[0].split("\n")[0]
        lines = [ln for ln in REGISTERED.splitlines() if not ln.startswith(key.split("=")[0])]
        if key.startswith("[pairs"):  # its run_config's table too
            lines = REGISTERED.replace("[pairs.reacher", change.rstrip("]")).splitlines()
        elif key == "[settings]":
            lines = REGISTERED.replace('[settings]\nmodel = "pved"\nshaping_form = "align"', change)
            lines = lines.splitlines()
        elif key.startswith("beta"):
            lines = REGISTERED.replace("beta = 0.1", change).splitlines()
        else:
            lines = [change, *lines]
        registered.write_text("\n".join(lines) + "\n")
        git(repo, "commit", "-q", "-am", "change")
    with pytest.raises(PvedError, match=message) as err:
        gate(tmp_path / "out", [registered])
    assert "\n" not in str(err.value)
    if "not a method beyond" in message or "has no number" in message:
        return  # a file of another method, or one unreadable, is refused even so
    # --exploratory runs the method anyway, labelled, and says why
    state = gate(tmp_path / "out", [registered], exploratory=True).status["pved-align"]
    assert state["status"] == EXPLORATORY and message.split(" ")[0] in state["why"]


def test_the_file_pins_the_settings_the_code_gives_the_runs() -> None:
    # the guide's code-level settings, beyond its recipe, and nothing that is the run's
    # identity, its PPO (the baseline's too) or its inputs
    pinned = run_config()
    assert {"align_anneal", "guide_limits", "shaping_form", "source_end"} <= set(pinned)
    assert {"grad_ratio", "d_gate"} <= set(pinned["guide_limits"])
    assert not {"beta", "model", "bank", "pair", "method", "stage"} & set(pinned)
    # PPO's settings and the episode counts, which the baseline shares but a later commit
    # could change, less the run's seed; and the config of the model it shapes with
    assert {"ppo", "eval_episodes", "final_eval_episodes", "model_config"} <= set(pinned)
    assert {"lr", "total_steps", "hidden_sizes"} <= set(pinned["ppo"])
    assert "seed" not in pinned["ppo"] and "seed" not in pinned["model_config"]
    assert {"lr", "epochs", "batch_size"} <= set(pinned["model_config"])
    # per pair: each pair's own (its bank's time base, its gate's score, ...)
    assert run_config("walker-hopper")["shaping_form"] == "align"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda text: re.sub(r"(?m)^align_anneal = .*$", "align_anneal = 0.123", text),
            r"pairs\.reacher\.run_config\.align_anneal is 0\.123, but this code gives "
            r"pved-align's evaluation runs 0\.\d",
        ),
        (
            lambda text: re.sub(r"grad_ratio = [0-9.e+-]+", "grad_ratio = 7.0", text),
            r"run_config\.guide_limits\.grad_ratio is 7\.0, but this code gives",
        ),
        (
            lambda text: re.sub(r"(?m)^guide_limits = .*\n", "", text),
            r"run_config\.guide_limits is none, but this code gives pved-align's evaluation "
            r"runs \{'grad_ratio'",
        ),
        (lambda text: text + "later_knob = 1\n", r"run_config\.later_knob is 1, but .* none$"),
        (
            lambda text: text.split("[pairs.reacher.run_config]")[0],
            "pairs.reacher has no 'run_config' table",
        ),
        (
            lambda text: re.sub(r"(?m)^(ppo = .*)\blr = [0-9.e+-]+", r"\1lr = 0.5", text),
            r"run_config\.ppo\.lr is 0\.5, but this code gives pved-align's evaluation runs",
        ),
        (
            lambda text: re.sub(r"(?m)^final_eval_episodes = \d+", "final_eval_episodes = 7", text),
            r"run_config\.final_eval_episodes is 7, but this code gives",
        ),
        (
            lambda text: re.sub(r"(?m)^(model_config = .*)\bepochs = \d+", r"\1epochs = 3", text),
            r"run_config\.model_config\.epochs is 3, but this code gives",
        ),
    ],
    ids=["changed", "nested", "missing", "extra", "no-table", "ppo", "episodes", "model"],
)
def test_a_file_whose_pinned_settings_are_not_the_codes_is_refused(
    tmp_path: Path, registered: Path, edit: Any, message: str
) -> None:
    registered.write_text(edit(REGISTERED))
    git(registered.parents[2], "commit", "-q", "-am", "change")
    with pytest.raises(PvedError, match=message) as err:
        gate(tmp_path / "out", [registered])
    assert "\n" not in str(err.value)
    state = gate(tmp_path / "out", [registered], exploratory=True).status["pved-align"]
    assert state["status"] == EXPLORATORY and "run_config" in state["why"]


def test_the_guides_code_must_be_the_registered_commits(
    tmp_path: Path, registered: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    repo = registered.parents[2]
    out = tmp_path / "out"
    assert gate(out, [registered]).status["pved-align"]["status"] == PREREGISTERED
    # code beyond the guide's may change
    (repo / "src/pved/analysis/code.py").write_text("x = 2\n")
    assert gate(out, [registered]).status["pved-align"]["status"] == PREREGISTERED
    # a change to the guide's code, its settings the same: in the working tree, committed
    # after the registration, or a new file
    guide = repo / "src/pved/rl/code.py"
    guide.write_text("x = 2\n")
    with pytest.raises(PvedError, match=r"src/pved/rl/code\.py differs from code_commit") as err:
        gate(out, [registered])
    assert "\n" not in str(err.value)
    git(repo, "commit", "-q", "-am", "a later fix")
    with pytest.raises(PvedError, match=r"src/pved/rl/code\.py differs from code_commit"):
        gate(out, [registered])
    state = gate(out, [registered], exploratory=True).status["pved-align"]
    assert state["status"] == EXPLORATORY and "differs from code_commit" in state["why"]
    guide.write_text("x = 1\n")
    git(repo, "commit", "-q", "-am", "undone")
    assert gate(out, [registered]).status["pved-align"]["status"] == PREREGISTERED
    (repo / "src/pved/models/new.py").write_text("y = 1\n")
    with pytest.raises(PvedError, match=r"src/pved/models/new\.py differs"):
        gate(out, [registered])
    (repo / "src/pved/models/new.py").unlink()
    # where git cannot say (code run from no git checkout), the gate refuses
    (tmp_path / "installed/pved").mkdir(parents=True)
    monkeypatch.setattr(preregistration, "PACKAGE", tmp_path / "installed/pved")
    with pytest.raises(PvedError, match="cannot compare the code with code_commit") as err:
        gate(out, [registered])
    assert "\n" not in str(err.value)


def test_a_file_without_the_code_commit_is_refused(tmp_path: Path, registered: Path) -> None:
    text = registered.read_text()
    registered.write_text(re.sub(r"(?m)^code_commit = .*\n", "", text))
    git(registered.parents[2], "commit", "-q", "-am", "no commit")
    with pytest.raises(PvedError, match="no 'code_commit' of the right type"):
        gate(tmp_path / "out", [registered])


def evaluation_run(out: Path, when: float) -> Path:
    """An evaluation run directory of pved-align (the registered β and init) started at
    ``when``."""
    run = out / "runs/reacher/transfer/pved-align-beta0.1-init2-src1/seed40000"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    os.utime(run / "config.json", (when, when))
    return run


def test_the_commit_must_predate_the_first_evaluation_run(tmp_path: Path, registered: Path) -> None:
    evaluation_run(tmp_path / "after", T0 + 60)
    assert gate(tmp_path / "after", [registered]).status["pved-align"]["status"] == PREREGISTERED
    evaluation_run(tmp_path / "before", T0 - 60)
    with pytest.raises(PvedError, match="not before pved-align's first evaluation run started"):
        gate(tmp_path / "before", [registered])
    # a run copied in from --stages-from counts as well
    with pytest.raises(PvedError, match="not before"):
        gate(tmp_path / "after", [registered], stages_from=[tmp_path / "before"])
    # the protocol's own record of when it first let the runs start, however late the
    # runs' files were written since
    out = tmp_path / "recorded"
    out.mkdir()
    (out / "preregistration.json").write_text(
        json.dumps({"evaluation_allowed_at": {"pved-align": T0 - 1}})
    )
    evaluation_run(out, T0 + 3600)
    with pytest.raises(PvedError, match="not before"):
        gate(out, [registered])


def test_the_record_keeps_the_first_start_and_marks_the_summary(
    tmp_path: Path, registered: Path
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    write_record(out, gate(out, [], exploratory=True))
    first = json.loads((out / "preregistration.json").read_text())["evaluation_allowed_at"]
    methods: dict[str, Any] = {"pved-align": {"runs": []}, "ppo": {"runs": []}}
    mark_summary(out, methods)
    assert methods["pved-align"][EXPLORATORY] is True and EXPLORATORY not in methods["ppo"]
    # a file committed after the protocol let the evaluation start cannot register it
    git(
        registered.parents[2],
        "commit",
        "-q",
        "--allow-empty",
        "-m",
        "x",
        when=int(first["pved-align"]) + 60,
    )
    registered.write_text(REGISTERED + "# again\n")
    git(registered.parents[2], "commit", "-q", "-am", "again", when=int(first["pved-align"]) + 60)
    with pytest.raises(PvedError, match="not before"):
        gate(out, [registered])
    write_record(out, gate(out, [], exploratory=True))
    again = json.loads((out / "preregistration.json").read_text())["evaluation_allowed_at"]
    assert again == first


def test_pved_protocol_refuses_before_any_work_and_marks_exploratory_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from helpers import run_cli
    from pved import __version__
    from pved.protocol.driver import summarize
    from pved.protocol.plan import PLAN_FILE, ProtocolPlan
    from pved.runs import atomic_write_json

    out = tmp_path / "out"
    argv = ["protocol", "--pair", "reacher", "--budget", "paper", "--out", out, "--methods"]
    code, _, err = run_cli(capsys, *argv, "pved-align", "ppo")
    assert code != 0 and "pved-align is beyond the paper" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    # the summary of an exploratory protocol labels the method's results
    plan = ProtocolPlan(["reacher"], ALIGN, "paper", out)
    out.mkdir()
    atomic_write_json(out / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    write_record(out, check_gate(["reacher"], ALIGN, "paper", out, None, (), exploratory=True))
    summary = summarize(out)
    methods = summary["pairs"]["reacher"]["methods"]
    assert methods["pved-align"][EXPLORATORY] is True and EXPLORATORY not in methods["ppo"]
    assert "| pved-align (exploratory) | 0/0 |" in (out / "summary.md").read_text()
