"""Issue 64's rule, applied: which method beyond the paper goes to the paper's budget
(``pved choose``; docs/decisions/protocol.md, "The `screen` budget, and the rule that picks
issue 64's method", its amendment, and "Applying the rule").

Input: one finished ``screen-auc`` protocol directory per pair (a run directory or its
record under docs/protocol/), each holding the candidates, ``ppo`` and ``ppo-aa``. The
rule, as committed before any screen ran, with the amendment's budget:

1. no candidate goes before every pair (:data:`pved.analysis.judge.FOUR`) has been
   screened, and a candidate not screened on a pair cannot go;
2. a candidate whose final score is behind PPO on any pair (the two-level 95% interval of
   candidate − PPO wholly below 0) is out, unless every candidate is;
3. of the rest, the one ahead of PPO in the normalised area under the learning curve (its
   interval wholly above 0) on the most pairs goes; candidates ahead on no pair tie at 0,
   and rule 4 decides (the screens' 15 runs decide little; the paper's budget decides);
4. a tie goes to the larger mean over the pairs of its area difference in units of the
   pair's A/A gap: the difference divided by the A/A noise floor, the largest |value| the
   interval of ppo-aa − ppo admits (:func:`pved.analysis.transfer_measures.aa_noise`; the
   unit written down before the last three pairs' screens had finished).

The measures are :func:`pved.analysis.transfer_measures.method_measures`' (the same
bootstrap as ``pved claims``). The winner's β and initialisation on each pair are its
screen's own selection (``summary.json``), written unchanged to a pre-registration file
(:func:`preregistration_text`; checked by :mod:`pved.protocol.preregistration`), with
the settings this code gives its evaluation runs (:func:`pinned_settings`), the commit
of the code it ran from and the numeric fingerprints of the code its screen runs were
made by.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pved.analysis.judge import AA_REFERENCE, FOUR, Judge, load_pairs, load_summary
from pved.analysis.run_curves import run_record
from pved.analysis.transfer_measures import BASELINE, REFERENCES, method_measures
from pved.config import ProtocolBudget, get_budget
from pved.errors import PvedError
from pved.protocol.plan import ProtocolPlan
from pved.protocol.preregistration import (
    CODE_COMMIT,
    PAPER_STEPS,
    RUN_CONFIG,
    code_commit,
    differing_keys,
    evaluation_configs,
    evaluation_settings,
    method_settings,
)
from pved.provenance import UNKNOWN, count_fingerprints, run_fingerprint
from pved.record_paths import record_path
from pved.runs import atomic_write_bytes
from pved.spec import toml_value
from pved.transfer.methods import get_method

SCREEN_BUDGET = "screen-auc"
"""The budget whose screens the rule reads (the amendment: β and init by the area)."""


@dataclasses.dataclass(frozen=True)
class Standing:
    """One candidate on one pair, as the rule reads it.

    Attributes:
        final, area: candidate − PPO of the final score and of the normalised area under
            the learning curve: ``{"value", "ci", "method_mean", "ppo_mean", "aa",
            "inside_aa", ...}`` (:func:`method_measures`' cells).
        beta, init: the screen's selection for the candidate on the pair.
        record: the screen's directory, as records name it (repository-relative).
        directory: the screen's directory as given.
        runs: the screen's evaluation runs of the candidate (its summary's entries).
    """

    pair: str
    method: str
    final: dict[str, Any]
    area: dict[str, Any]
    beta: float
    init: int
    record: str
    directory: Path = Path()
    runs: tuple[dict[str, Any], ...] = ()

    @property
    def behind(self) -> bool:
        """The final score's interval lies wholly below 0 (rule 2)."""
        return bool(self.final["ci"][1] < 0)

    @property
    def ahead(self) -> bool:
        """The area's interval lies wholly above 0 (rule 3)."""
        return bool(self.area["ci"][0] > 0)

    @property
    def area_units(self) -> float:
        """The area difference over the pair's A/A noise floor (rule 4)."""
        noise, value = float(self.area["aa"]["noise"]), float(self.area["value"])
        if noise > 0:
            return value / noise
        return math.copysign(math.inf, value) if value else 0.0


@dataclasses.dataclass(frozen=True)
class Choice:
    """What the rule decided, and from what.

    Attributes:
        standings: candidate -> pair -> :class:`Standing`, for the pairs it was screened on.
        missing: the pairs of the four with no screen among the inputs.
        winner: the candidate that goes to the paper's budget; None with ``why``.
        why: one line: how the winner was found, or why there is none yet.
    """

    standings: dict[str, dict[str, Standing]]
    missing: tuple[str, ...]
    winner: str | None
    why: str

    def screened_everywhere(self, method: str) -> bool:
        """Whether ``method`` was screened on all four pairs."""
        return not self.missing and set(self.standings[method]) >= set(FOUR)

    def out(self, method: str) -> list[str]:
        """The pairs where ``method``'s final score is behind PPO's."""
        return [p for p, s in self.standings[method].items() if s.behind]

    def ahead(self, method: str) -> int:
        """On how many pairs ``method``'s area is ahead of PPO's."""
        return sum(s.ahead for s in self.standings[method].values())

    def tie_score(self, method: str) -> float:
        """The mean over pairs of the area difference in A/A units (rule 4)."""
        units = [s.area_units for s in self.standings[method].values()]
        return sum(units) / len(units) if units else float("nan")


def _standing(
    pair: str, method: str, cells: dict[str, Any], entry: dict[str, Any], directory: Path
) -> Standing:
    record = record_path(directory)
    for measure in ("final", "auc"):
        cell = cells[measure]
        if "reason" in cell:
            raise PvedError(f"{record}: {method} on {pair}: no {measure} ({cell['reason']})")
        if not isinstance(cell["aa"], dict):
            raise PvedError(
                f"{record}: {pair} has no usable {AA_REFERENCE} runs ({cell['aa']}); the rule "
                "reads every difference beside the pair's A/A gap"
            )
    beta, init = entry.get("beta"), entry.get("init")
    if not isinstance(beta, int | float) or not isinstance(init, int):
        raise PvedError(f"{record}: {method} on {pair} has no selected beta and init")
    runs = tuple(entry.get("runs") or ())
    return Standing(
        pair, method, cells["final"], cells["auc"], float(beta), init, record, directory, runs
    )


def _check_finished(directory: Path) -> None:
    """Refuse a screen that is not whole: runs failed or blocked, or a method with runs
    still missing (a ``summary.json`` is written after such a run too, and by ``pved
    plot`` at any time)."""
    summary = load_summary(directory)
    if summary.get("failed") or summary.get("blocked"):
        raise PvedError(f"{directory}: runs failed or were blocked; finish the screen first")
    for pair, entry in summary["pairs"].items():
        for method, m in (entry.get("methods") or {}).items():
            planned, done = m.get("runs_planned"), m.get("runs_finished")
            if m.get("missing") or (isinstance(planned, int) and done != planned):
                raise PvedError(
                    f"{directory}: {method} on {pair} has {done} of {planned} runs; "
                    "finish the screen first"
                )


def choose(directories: Sequence[Path | str], candidates: Sequence[str] = ()) -> Choice:
    """Apply the rule (module docstring) to the screens in ``directories``. ``candidates``:
    the methods to choose among (default: every method of the screens that is not a
    reference). Raises PvedError (one line) for a directory that is no finished
    ``screen-auc`` protocol, a pair without ``ppo``/``ppo-aa`` runs, or a named candidate
    that no screen holds."""
    for directory in directories:
        _check_finished(Path(directory))
    pairs = load_pairs([Path(d) for d in directories])
    for name, p in pairs.items():
        if name not in FOUR:
            raise PvedError(
                f"{p.directory}: {name} is not one of the rule's pairs ({', '.join(FOUR)})"
            )
        if p.budget != SCREEN_BUDGET:
            raise PvedError(
                f"{p.directory}: a {p.budget!r} protocol; the rule reads {SCREEN_BUDGET!r} "
                "screens (docs/decisions/protocol.md)"
            )
        for ref in (BASELINE, AA_REFERENCE):
            if not (p.methods.get(ref) or {}).get("runs"):
                raise PvedError(f"{p.directory}: {name} has no {ref} runs")
    found = list(
        dict.fromkeys(
            m
            for p in pairs.values()
            for m, e in p.methods.items()
            if m not in REFERENCES and (e or {}).get("runs")
        )
    )
    unknown = [m for m in candidates if m not in found]
    if unknown:
        raise PvedError(f"no screen holds runs of {', '.join(unknown)}")
    methods = list(candidates) or found
    for m in methods:
        if get_method(m).paper:
            raise PvedError(f"{m} is the paper's: the rule chooses among methods beyond it")
    judge = Judge(pairs)
    standings: dict[str, dict[str, Standing]] = {m: {} for m in methods}
    for name, p in pairs.items():
        held = [m for m in methods if (p.methods.get(m) or {}).get("runs")]
        for m in held:
            cells = method_measures({name: p}, m, judge)["pairs"][name]
            standings[m][name] = _standing(name, m, cells, p.methods[m], p.directory)
    missing = tuple(pair for pair in FOUR if pair not in pairs)
    partial = Choice(standings, missing, None, "")
    return dataclasses.replace(partial, **_decide(partial, methods))


def _decide(c: Choice, methods: Sequence[str]) -> dict[str, Any]:
    """Rules 1-4 on the standings: ``{"winner", "why"}``."""
    if c.missing:
        return {"winner": None, "why": f"not yet screened: {', '.join(c.missing)} (rule 1)"}
    ready = [m for m in methods if c.screened_everywhere(m)]
    if not ready:
        return {"winner": None, "why": "no candidate was screened on every pair (rule 1)"}
    kept = [m for m in ready if not c.out(m)] or ready
    note = "" if any(not c.out(m) for m in ready) else "; every candidate behind somewhere"
    most = max(c.ahead(m) for m in kept)
    best = [m for m in kept if c.ahead(m) == most]
    if len(best) == 1:
        return {"winner": best[0], "why": f"ahead in area on {most} of 4 pairs (rule 3){note}"}
    best.sort(key=lambda m: c.tie_score(m), reverse=True)
    top = best[0]
    tied = [m for m in best if c.tie_score(m) == c.tie_score(top)]
    if len(tied) > 1:
        return {"winner": None, "why": f"{' and '.join(tied)} tie by rules 3 and 4"}
    return {
        "winner": top,
        "why": (
            f"ahead in area on {most} of 4 pairs like {', '.join(best[1:])}; the larger mean "
            f"area difference in A/A units, {c.tie_score(top):+.2f} (rule 4){note}"
        ),
    }


def _n(x: float) -> str:
    return f"{x:+.3f}"


def choice_table(c: Choice) -> str:
    """The rule's inputs and verdict as Markdown: a row per candidate and pair, then a row
    per candidate, then the decision."""
    lines = [
        "| candidate | pair | β, init | final − PPO [95% CI] | behind | area − PPO [95% CI] "
        "| ahead | area / A/A noise | screen |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method, by_pair in c.standings.items():
        for pair in [p for p in FOUR if p in by_pair] + sorted(set(by_pair) - set(FOUR)):
            s = by_pair[pair]
            f, a = s.final, s.area
            lines.append(
                f"| `{method}` | {pair} | {s.beta:g}, {s.init} | {_n(f['value'])} "
                f"[{_n(f['ci'][0])}, {_n(f['ci'][1])}] | {'yes' if s.behind else 'no'} | "
                f"{_n(a['value'])} [{_n(a['ci'][0])}, {_n(a['ci'][1])}] | "
                f"{'yes' if s.ahead else 'no'} | {s.area_units:+.2f} | {s.record} |"
            )
    lines += ["", "| candidate | screened on | behind on | ahead on | mean area / A/A noise |"]
    lines.append("|---|---|---|---|---|")
    for method, by_pair in c.standings.items():
        lines.append(
            f"| `{method}` | {len(by_pair)} of 4 | {', '.join(c.out(method)) or '–'} | "
            f"{c.ahead(method)} | {c.tie_score(method):+.2f} |"
        )
    verdict = f"`{c.winner}` goes to the paper's budget" if c.winner else "no candidate goes yet"
    return "\n".join([*lines, "", f"**{verdict}**: {c.why}."])


def choice_json(c: Choice) -> dict[str, Any]:
    """The choice as plain data (``pved choose --json``)."""
    return {
        "winner": c.winner,
        "why": c.why,
        "missing": list(c.missing),
        "candidates": {
            m: {
                "out": c.out(m),
                "ahead": c.ahead(m),
                "area_in_aa_units": c.tie_score(m),
                "pairs": {
                    p: {
                        "beta": s.beta,
                        "init": s.init,
                        "screen": s.record,
                        "final": {"value": s.final["value"], "ci": list(s.final["ci"])},
                        "area": {"value": s.area["value"], "ci": list(s.area["ci"])},
                        "area_aa_noise": s.area["aa"]["noise"],
                        "behind": s.behind,
                        "ahead": s.ahead,
                    }
                    for p, s in by_pair.items()
                },
            }
            for m, by_pair in c.standings.items()
        },
    }


def check_registered_budget(budget: str) -> ProtocolBudget:
    """``budget``, which a pre-registration may register: one of the paper's length whose
    evaluation seeds are none of the screens' tuning seeds; else PvedError (one line)."""
    b = get_budget(budget)
    if b.steps_budget != PAPER_STEPS:
        raise PvedError(f"--budget {budget}: a pre-registration gates the paper's budgets")
    overlap = sorted(set(get_budget(SCREEN_BUDGET).tuning_seeds) & set(b.evaluation_seeds))
    if overlap:
        raise PvedError(f"--budget {budget} evaluates on the screens' tuning seeds {overlap}")
    return b


def _registered(c: Choice, budget: str, pairs: Sequence[str]) -> str:
    """The winner, once a file of it at ``budget`` on ``pairs`` can be written; else
    PvedError (one line): no winner, ``budget`` not one of the paper's length, or a pair
    not screened."""
    check_registered_budget(budget)
    if c.winner is None:
        raise PvedError(f"no method to pre-register: {c.why}")
    if not pairs:
        raise PvedError("--pairs: name at least one pair")
    unknown = [p for p in pairs if p not in c.standings[c.winner]]
    if unknown:
        raise PvedError(f"--pairs: {', '.join(unknown)} not screened")
    return c.winner


@dataclasses.dataclass(frozen=True)
class Pinned:
    """What a pre-registration pins of the winner beyond its β and init, pair by pair.

    Attributes:
        run_config: the settings this code gives its evaluation runs at the registered
            budget (:func:`pved.protocol.preregistration.evaluation_settings`: the
            guide's anneal and limits, Eq. 10's entries, PPO's, the model's config...),
            which the gate compares with each evaluation run's.
        fingerprints: the numeric fingerprints its screen runs were made under, with
            counts (:mod:`pved.provenance`), for provenance.
        drift: where its screen runs had other settings: the keys, or that a run records
            no config (pairs without a difference are left out).
    """

    run_config: dict[str, dict[str, Any]]
    fingerprints: dict[str, dict[str, int]]
    drift: dict[str, list[str]]

    def drift_line(self, method: str) -> str | None:
        """One line saying where this code's settings are not the screens', or None: a
        fix made after a screen is allowed, but the file must not hide it."""
        if not self.drift:
            return None
        where = "; ".join(f"{p}: {', '.join(keys)}" for p, keys in self.drift.items())
        return (
            f"{method}'s settings in this code differ from those its screens ran under "
            f"({where}); the file pins this code's"
        )


def _drift(settings: dict[str, Any], baseline: dict[str, Any], records: list[Any]) -> list[str]:
    """The keys of ``settings`` (this code's) that a screen run's config had otherwise."""
    keys: set[str] = set()
    for record in records:
        config = record.get("config") if isinstance(record, dict) else None
        if not isinstance(config, dict):
            keys.add("a run records no config")
            continue
        keys.update(differing_keys(method_settings(config, baseline), settings))
    return sorted(keys)


def pinned_settings(c: Choice, budget: str, pairs: Sequence[str]) -> Pinned:
    """:class:`Pinned` for the winner's evaluation at ``budget`` on ``pairs``: the
    settings from the config this code's :func:`pved.experiments.transfer_spec.
    transfer_spec` gives each of its evaluation runs (at the screens' β and init), as a
    protocol of that budget would make them, and its screen runs' records
    (``config.json``, or the published record's copy). PvedError (one line) as
    :func:`preregistration_text`'s."""
    winner = _registered(c, budget, pairs)
    tuning = list(get_budget(SCREEN_BUDGET).tuning_seeds)
    standings = c.standings[winner]
    fixed = {
        pair: {
            winner: {
                "beta": standings[pair].beta,
                "init": standings[pair].init,
                "protocol": standings[pair].record,
                "budget": SCREEN_BUDGET,
                "tuning_seeds": tuning,
                "candidates": [],
            }
        }
        for pair in pairs
    }
    run_config: dict[str, dict[str, Any]] = {}
    fingerprints: dict[str, dict[str, int]] = {}
    drift: dict[str, list[str]] = {}
    with tempfile.TemporaryDirectory() as tmp:  # the plan is only read, never run
        plan = ProtocolPlan(pairs, [winner], budget, Path(tmp), fixed)
        for pair in pairs:
            every = evaluation_settings(plan, pair, winner)
            if any(settings != every[0] for settings in every):
                raise PvedError(f"{winner} on {pair}: its evaluation runs get unequal settings")
            s = standings[pair]
            records = [run_record(s.directory, r) for r in s.runs]
            run_config[pair] = every[0]
            fingerprints[pair] = count_fingerprints(
                [run_fingerprint(r) if r else UNKNOWN for r in records]
            )
            # the screens ran at another budget: only what the method adds is compared
            baseline, configs = evaluation_configs(plan, pair, winner)
            keys = _drift(method_settings(configs[0], baseline), baseline, records)
            if keys:
                drift[pair] = keys
    return Pinned(run_config, fingerprints, drift)


def _table(values: dict[str, Any]) -> list[str]:
    """``key = value`` lines of a TOML table, keys quoted as the spec writer quotes them."""
    return [toml_value({k: v})[2:-2] for k, v in values.items()]


def preregistration_text(
    c: Choice,
    budget: str,
    pairs: Sequence[str],
    date: datetime.date | None = None,
    pinned: Pinned | None = None,
    commit: str | None = None,
) -> str:
    """The pre-registration file (:mod:`pved.protocol.preregistration`) of the winner's
    evaluation at ``budget`` on ``pairs``: its recipe, and on each pair the β and init its
    screen chose, unchanged, the fingerprints of its screen runs and the settings this
    code gives its evaluation runs (``pinned``, default :func:`pinned_settings`), and the
    commit of the code it ran from (``commit``, default HEAD of this code's checkout;
    the gate refuses where the guide's code differs from it). PvedError where there is no
    winner, ``budget`` is not one of the paper's length, a pair was not screened, or git
    cannot say the commit."""
    winner = _registered(c, budget, pairs)
    b = get_budget(budget)
    pinned = pinned or pinned_settings(c, budget, pairs)
    tuning = list(get_budget(SCREEN_BUDGET).tuning_seeds)
    recipe = get_method(winner)
    settings: dict[str, Any] = {
        "model": recipe.model,
        "shaping_form": recipe.shaping_form,
        "train_reward": recipe.train_reward,
    }
    if recipe.anneal is not None:
        settings["anneal"] = recipe.anneal
    day = date or datetime.datetime.now(datetime.UTC).date()
    drift = pinned.drift_line(winner)
    lines = [
        "# Issue 64's rule applied to the screens (`pved choose`; docs/decisions/protocol.md):",
        f"# {c.why}.",
        *([f"# {drift}."] if drift else []),
        f"method = {toml_value(winner)}",
        f"budget = {toml_value(budget)}",
        f"date = {day.isoformat()}",
        f"evaluation_seeds = {len(b.evaluation_seeds)}",
        f"source_policies = {b.source_policies}",
        f"tuning_seeds = {toml_value(tuning)}",
        f"tuning_budget = {toml_value(SCREEN_BUDGET)}",
        f"{CODE_COMMIT} = {toml_value(commit or code_commit())}",
        "",
        "[settings]",
        *_table(settings),
    ]
    for pair in pairs:
        s = c.standings[winner][pair]
        lines += ["", f"[pairs.{pair}]", f"beta = {s.beta!r}", f"init = {s.init}"]
        lines.append(f"screen = {toml_value(s.record)}")
        lines.append(f"screen_fingerprints = {toml_value(pinned.fingerprints[pair])}")
        lines += ["", f"[pairs.{pair}.{RUN_CONFIG}]", *_table(pinned.run_config[pair])]
    return "\n".join(lines) + "\n"


def write_preregistration(c: Choice, path: Path | str, budget: str, pairs: Sequence[str]) -> Path:
    """Write :func:`preregistration_text` to ``path`` atomically, its folder made where
    missing; an existing file is refused (a registration is changed by hand, in a commit
    that says why). Where this code's settings are not those the screens ran under, says
    so in one line on stderr (:meth:`Pinned.drift_line`)."""
    path = Path(path)
    if path.exists():
        raise PvedError(f"--write {path}: exists; a pre-registration is never overwritten")
    pinned = pinned_settings(c, budget, pairs)
    text = preregistration_text(c, budget, pairs, pinned=pinned)
    atomic_write_bytes(path, text.encode())  # makes its folder (docs/preregistration/)
    drift = pinned.drift_line(c.winner or "")
    if drift:
        print(f"pved choose: {drift}", file=sys.stderr)
    return path


__all__ = [
    "SCREEN_BUDGET",
    "Choice",
    "Pinned",
    "Standing",
    "check_registered_budget",
    "choice_json",
    "choice_table",
    "choose",
    "pinned_settings",
    "preregistration_text",
    "write_preregistration",
]
