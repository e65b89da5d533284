"""Property-based (Hypothesis): every numeric option of every verb, given a value out of
its range or of the wrong type, is refused before any work: exit status 2, one
``pved: error:`` line naming the option, no traceback, no file written. The same holds
for the stage functions the verbs are thin layers over (a ``PvedError`` naming the
option), where a notebook can pass anything: a string, a bool, a float for a count.

Derandomized and without an example database, so that CI runs the same examples in
the same few seconds every time.
"""

from __future__ import annotations

import contextlib
import io
import math
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pved.cli import main
from pved.diagnostics import transferred
from pved.errors import PvedError
from pved.experiments import stages
from pved.pretrained import pretrained_policy_path

POLICY = str(pretrained_policy_path("Reacher3", "Push"))  # any existing file will do
SEED_MAX = 2**32 - 1


@dataclass(frozen=True)
class Kind:
    """What an option takes: integers in [low, high], or reals in [low, high]
    (``open_low``: low itself excluded; ``infinite``: +inf allowed)."""

    integer: bool
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    infinite: bool = False

    def accepts(self, x: float) -> bool:
        if math.isnan(x) or (math.isinf(x) and not (self.infinite and x > 0)):
            return False
        if self.low is not None and (x < self.low or (self.open_low and x == self.low)):
            return False
        return self.high is None or x <= self.high


COUNT = Kind(integer=True, low=1)  # episodes, steps, epochs
COUNT0 = Kind(integer=True, low=0)  # eval interval, shaping start, marks, retries
SEED = Kind(integer=True, low=0, high=SEED_MAX)
NONNEG = Kind(integer=False, low=0.0)  # beta, claim minutes
UNIT = Kind(integer=False, low=0.0, high=1.0)  # quantile, gamma
POSITIVE = Kind(integer=False, low=0.0, open_low=True)  # audit betas, deadline, MiB
SECONDS = Kind(integer=False, low=0.0, infinite=True)  # checkpoint seconds


def _parses(text: str, integer: bool) -> bool:
    try:
        int(text) if integer else float(text)
    except ValueError:
        return False
    return True


def bad_numbers(kind: Kind) -> st.SearchStrategy[float]:
    """Numbers the option does not take (ints for an integer option, reals otherwise)."""
    if kind.integer:
        low = int(kind.low) if kind.low is not None else None
        parts = [st.integers(max_value=low - 1)] if low is not None else []
        if kind.high is not None:
            parts.append(st.integers(min_value=int(kind.high) + 1))
        return st.one_of(*parts)
    reals = st.floats(allow_nan=True, allow_infinity=True)
    return reals.filter(lambda x: not kind.accepts(x))


def bad_cli_values(kind: Kind) -> st.SearchStrategy[str]:
    """What a user could type for the option that it does not take: a number out of
    range, a real for a count, words."""
    words = st.text(max_size=12).filter(lambda t: not _parses(t, kind.integer))
    values = [bad_numbers(kind).map(repr), words]
    if kind.integer:  # 2.0, 1e3, nan: not counts
        values.append(st.floats().map(repr))
    return st.one_of(*values)


def bad_python_values(kind: Kind) -> st.SearchStrategy[Any]:
    """What a notebook could pass that the argument does not take: a number out of
    range, a bool, a string, a list, a real (even 3.0) for a count."""
    values = [
        bad_numbers(kind),
        st.booleans(),
        st.text(max_size=8),
        st.lists(st.integers(), max_size=2),
    ]
    if kind.integer:
        values.append(st.floats())
    return st.one_of(*values)


# (argv before the option, the option, what it takes); {tmp} is the example's directory
CLI: list[tuple[tuple[str, ...], str, Kind]] = [
    (("train-policy", "--agent", "Reacher4", "--task", "Push", "--runs", "{tmp}/r"), o, k)
    for o, k in (("--steps", COUNT), ("--seed", SEED), ("--eval-episodes", COUNT),
                 ("--checkpoint-seconds", SECONDS))
] + [
    (("collect-pairs", "--runs", "{tmp}/r"), o, k)
    for o, k in (("--episodes", COUNT), ("--seed", SEED))
] + [
    (("train-model", "--runs", "{tmp}/r"), o, k) for o, k in (("--epochs", COUNT), ("--seed", SEED))
] + [
    (("build-bank", "--runs", "{tmp}/r"), o, k)
    for o, k in (("--episodes", COUNT), ("--seed", SEED))
] + [
    (("transfer", "--runs", "{tmp}/r", "--model", m), o, k)
    for m in ("pved", "ppo")
    for o, k in (("--steps", COUNT), ("--seed", SEED), ("--beta", NONNEG),
                 ("--eval-every", COUNT0), ("--eval-episodes", COUNT),
                 ("--final-eval-episodes", COUNT), ("--shaping-start", COUNT0),
                 ("--checkpoint-seconds", SECONDS))
] + [
    (("evaluate", "--policy", POLICY, "--env", "pved/Reacher3Push-v0"), o, k)
    for o, k in (("--episodes", COUNT), ("--seed", SEED))
] + [
    (("tsne", "--model", POLICY, "--target-policy", POLICY, "--out", "{tmp}/t"), o, k)
    for o, k in (("--episodes", COUNT), ("--marks", COUNT0), ("--later-frames", COUNT0),
                 ("--later-frame-stride", COUNT), ("--seed", SEED))
] + [
    (("bound", "--model", POLICY, "--target-policy", POLICY), o, k)
    for o, k in (("--episodes", COUNT), ("--quantile", UNIT), ("--gamma", UNIT),
                 ("--seed", SEED))
] + [
    (("audit-shaping", "--model", POLICY, "--bank", POLICY, "--out", "{tmp}/a.json"), o, k)
    for o, k in (("--steps", COUNT), ("--betas", POSITIVE), ("--seed", SEED))
] + [
    (("audit-likelihood", "--dataset", POLICY, "--runs", "{tmp}/r"), o, k)
    for o, k in (("--epochs", COUNT), ("--seed", SEED))
] + [
    (("video", "--policy", POLICY, "--env", "pved/Reacher3Push-v0", "--out", "{tmp}/v.gif"),
     o, k)
    for o, k in (("--max-steps", COUNT), ("--seed", SEED))
] + [
    (("protocol", "--pair", "reacher", "--out", "{tmp}/p", "--backend", "processes"), o, k)
    for o, k in (("--workers", COUNT), ("--retries", COUNT0),
                 ("--checkpoint-seconds", SECONDS))
] + [
    (("batch", "export", "--protocol", "{tmp}/p", "--batch", "{tmp}/b"), o, k)
    for o, k in (("--limit", COUNT), ("--skip", COUNT0), ("--claim-minutes", NONNEG),
                 ("--max-input-mib", POSITIVE))
] + [
    (("batch", "run", "--batch", "{tmp}/b"), o, k)
    for o, k in (("--workers", COUNT), ("--deadline-s", POSITIVE), ("--start-by-s", NONNEG))
] + [
    (("demo", "--runs", "{tmp}/r", "--out", "{tmp}/o"), o, k)
    for o, k in (("--steps", COUNT), ("--seeds", SEED), ("--jobs", COUNT))
] + [
    (("report", "--runs", "{tmp}/r", "--out", "{tmp}/o"), "--seeds", SEED),
]  # fmt: skip


@contextlib.contextmanager
def empty_directory() -> Iterator[Path]:
    """A fresh directory, the working directory while in use (so that a verb's relative
    defaults land in it too), removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix="pved-prop-"))
    try:
        with contextlib.chdir(path):
            yield path
    finally:
        shutil.rmtree(path)


# What each verb's work starts with: replaced, for these tests, by a function that
# fails them, so that a bad value that slipped through its check ends the example at
# once (instead of training for an hour), and "before any work" is part of the property.
WORK = (
    "pved.experiments.stages.train_ppo",
    "pved.experiments.stages.collect_episode_pairs",
    "pved.experiments.stages.fit_model",
    "pved.experiments.stages.build_source_bank",
    "pved.experiments.stages.evaluate_policy",
    "pved.diagnostics.transferred.embed_rollouts",
    "pved.diagnostics.transferred.theorem1_bound",
    "pved.diagnostics.shaping_audit.audit_transfer_start",
    "pved.diagnostics.video._rollout_frames",
    "pved.models.train.train_model",
    "pved.protocol.driver.run_jobs",
    "pved.experiments.demo.collect_pairs",
)


class WorkStarted(AssertionError):
    """A verb began its work on a value it should have refused."""


@pytest.fixture(scope="module", autouse=True)
def no_work() -> Iterator[None]:
    def refuse(*args: object, **kwargs: object) -> None:
        raise WorkStarted

    with pytest.MonkeyPatch.context() as patch:
        for target in WORK:
            patch.setattr(target, refuse)
        yield


PROPERTY = settings(max_examples=300, deadline=None, derandomize=True, database=None)


@PROPERTY
@given(data=st.data(), case=st.sampled_from(CLI))
def test_every_verb_refuses_a_bad_option_value_in_one_line_before_any_work(
    data: st.DataObject, case: tuple[tuple[str, ...], str, Kind]
) -> None:
    before, option, kind = case
    value = data.draw(bad_cli_values(kind), label=option)
    with empty_directory() as tmp:
        argv = [a.format(tmp=tmp) for a in before] + [f"{option}={value}"]
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(argv)
        lines = err.getvalue().strip().splitlines()
        assert code == 2, (argv, err.getvalue())
        assert len(lines) == 1 and lines[0].startswith("pved: error:"), err.getvalue()
        assert "Traceback" not in err.getvalue() and option in lines[0], lines[0]
        assert not list(tmp.iterdir()), f"{argv} wrote {list(tmp.rglob('*'))}"


# (the stage function, its leading arguments, the argument, its option, what it takes)
API: list[tuple[Callable[..., Any], tuple[Any, ...], str, str, Kind]] = [
    (stages.train_policy, ("Reacher4", "Push"), a, o, k)
    for a, o, k in (("steps", "--steps", COUNT), ("seed", "--seed", SEED),
                    ("eval_episodes", "--eval-episodes", COUNT),
                    ("checkpoint_every_s", "--checkpoint-seconds", SECONDS))
] + [
    (stages.collect_pairs, ("reacher",), a, o, k)
    for a, o, k in (("episodes", "--episodes", COUNT), ("seed", "--seed", SEED))
] + [
    (stages.train_model, ("reacher",), a, o, k)
    for a, o, k in (("epochs", "--epochs", COUNT), ("seed", "--seed", SEED))
] + [
    (stages.build_bank, ("reacher",), a, o, k)
    for a, o, k in (("episodes", "--episodes", COUNT), ("seed", "--seed", SEED))
] + [
    (stages.transfer, ("reacher", m), a, o, k)
    for m in ("pved", "ppo")
    for a, o, k in (("steps", "--steps", COUNT), ("seed", "--seed", SEED),
                    ("beta", "--beta", NONNEG), ("eval_every", "--eval-every", COUNT0),
                    ("eval_episodes", "--eval-episodes", COUNT),
                    ("final_eval_episodes", "--final-eval-episodes", COUNT),
                    ("shaping_start", "--shaping-start", COUNT0),
                    ("checkpoint_every_s", "--checkpoint-seconds", SECONDS))
] + [
    (stages.evaluate, (POLICY, "pved/Reacher3Push-v0"), a, o, k)
    for a, o, k in (("episodes", "--episodes", COUNT), ("seed", "--seed", SEED))
] + [
    (transferred.bound, ("reacher", POLICY, POLICY), a, o, k)
    for a, o, k in (("episodes", "--episodes", COUNT), ("quantile", "--quantile", UNIT),
                    ("gamma", "--gamma", UNIT), ("seed", "--seed", SEED))
]  # fmt: skip


@PROPERTY
@given(data=st.data(), case=st.sampled_from(API))
def test_every_stage_function_refuses_a_bad_argument_naming_its_option(
    data: st.DataObject, case: tuple[Callable[..., Any], tuple[Any, ...], str, str, Kind]
) -> None:
    fn, args, name, option, kind = case
    value = data.draw(bad_python_values(kind), label=name)
    with empty_directory() as tmp:
        runs = {"runs_root": tmp / "r"} if fn not in (stages.evaluate, transferred.bound) else {}
        with pytest.raises(PvedError) as caught:
            fn(*args, **runs, **{name: value})
        message = str(caught.value)
        assert len(message.splitlines()) == 1 and option in message, message
        assert not list(tmp.iterdir())
