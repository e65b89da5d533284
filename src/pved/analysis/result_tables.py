"""The tables ``pved publish`` writes into the pages (:data:`TABLES`), each made from the
committed records under docs/protocol/ by :class:`Records`: one reading of the records and
one judge over them, with the project's one interval method, the two-level bootstrap over
source policies and PPO seeds (:func:`pved.analysis.bootstrap.bootstrap_mean` for one method,
:func:`pved.analysis.bootstrap.bootstrap_difference` for two, judged as ``pved claims`` and
``pved scoreboard`` judge, :mod:`pved.analysis.judge`). The one exception, the IQM's
interval, is the record's (rliable, over runs) and says "one-level" in its header. Every
verdict a table prints is noted (:attr:`Records.verdicts`), so that
:func:`pved.analysis.publish.verdict_flips` can ask whether any depends on the
resampling's seed. One idea, however long: every table the pages print, each a short
function of the records, so that a page and its records cannot disagree.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pved.analysis.bootstrap import REPS, SEED
from pved.analysis.claims import CLAIMS as PAPER_CLAIMS
from pved.analysis.claims import combine, family_wise
from pved.analysis.judge import (
    FOUR,
    HOLDS,
    NOT_HOLD,
    PAIR_TITLES,
    UNDECIDED,
    Judge,
    PairSummary,
    load_pairs,
)
from pved.analysis.power import RUNS, SOURCES, power_rows, power_table
from pved.analysis.scoreboard import AHEAD, load_merged, pair_row
from pved.analysis.transfer_goal import transfer_goal, transfer_goal_markdown
from pved.analysis.transfer_measures import INSIDE_AA, method_measures
from pved.errors import PvedError

RECORDS = Path("docs") / "protocol"
"""Where the committed records are, under the repository root."""
OTHERS = ("pved-state-only", "pved-shared-only", "pved-det-shared", "pved-vae", "gupta2017")
"""The methods a "best other method" column chooses from: PVED's ablations and Gupta et al."""
SHORT = {
    "pved-state-only": "state-only",
    "pved-shared-only": "shared-only",
    "pved-det-shared": "det-shared",
    "pved-vae": "VAE",
    "gupta2017": "Gupta et al.",
    "pved-align": "align",
    "pved-align-short": "-short",
}
UNITS = {"success_rate": "success", "x_position_mean": "m"}
CLAIM_NAMES = {
    1: "1 PVED beats PPO everywhere; PPO fails on peg and Hopper",
    2: "2 PVED beats Gupta et al.",
    3: "3 on the Ant only PVED and PVED-VAE beat PPO",
    4: "4 PVED beats state-only; state-only worse than Gupta",
    5: "5 PVED beats shared-only",
    6: "6 PVED vs det-shared",
    7: "7 PVED beats PVED-VAE (similar on the Ant)",
}
"""Each claim's short name in the tables (the statements: :data:`pved.analysis.claims.CLAIMS`)."""
BUDGETS = {
    "quick": [f"{p}-quick" for p in FOUR],
    "paper": [f"{p}-paper" for p in FOUR],
    "paper-wide": ["reacher-paper-wide"],
}
"""The protocol directories each budget's claims are judged on."""
ALIGN_PAPER = {
    "reacher": [
        "reacher-paper-align",
        "pved-align-short=reacher-paper-align-short",
        "pved=reacher-paper",
        "oracle=reacher-paper",
    ],
    "walker-hopper": [
        "walker-hopper-paper-align",
        "pved=walker-hopper-paper",
        "oracle=walker-hopper-paper",
    ],
    "jaco-fetch": ["jaco-fetch-paper-align", "pved=jaco-fetch-paper", "oracle=jaco-fetch-paper"],
    "humanoid-ant": [
        "humanoid-ant-paper-align",
        "pved=humanoid-ant-paper-eq10",
        "oracle=humanoid-ant-paper",
    ],
}
"""Issue 51 at the paper's budget: each pair's inputs (as ``pved scoreboard`` takes them)."""
SCREENS = (
    ("reacher", "pved-align", "reacher-quick-align"),
    ("reacher", "pved-align-short", "reacher-quick-align-short"),
    ("reacher", "pved-potential", "reacher-quick-potential"),
    ("reacher", "pved-anneal", "reacher-quick-anneal"),
    ("walker-hopper", "pved-align", "walker-hopper-quick-align"),
    ("jaco-fetch", "pved-align", "jaco-fetch-quick-align"),
    ("jaco-fetch", "pved-align-short", "jaco-fetch-quick-align-short"),
    ("humanoid-ant", "pved-align", "humanoid-ant-quick-align"),
)
"""Issue 51's screens at the ``quick`` budget: (pair, method, its screen's directory)."""
SCREENS_64 = (
    ("reacher", "pved-prior", "reacher-screen"),
    ("reacher", "pved-align", "reacher-screen-align"),
    ("reacher", "pved-prior", "reacher-screen-auc"),
    ("reacher", "pved-align", "reacher-screen-auc"),
    ("reacher", "pved-prior", "reacher-screen-auc-bar"),
    ("reacher", "pved-align", "reacher-screen-auc-bar"),
    ("jaco-fetch", "pved-prior", "jaco-fetch-screen-auc"),
    ("jaco-fetch", "pved-align", "jaco-fetch-screen-auc"),
    ("walker-hopper", "pved-prior", "walker-hopper-screen-auc-gate"),
    ("walker-hopper", "pved-align", "walker-hopper-screen-auc-gate"),
    ("humanoid-ant", "pved-prior", "humanoid-ant-screen-auc"),
    ("humanoid-ant", "pved-align", "humanoid-ant-screen-auc"),
)
"""Issue 64's screens at the ``screen`` and ``screen-auc`` budgets (seeds no other budget
runs): (pair, method, its screen's directory, which holds its ppo and ppo-aa runs too)."""
PAPER_ORDER = ("walker-hopper", "jaco-fetch", "reacher", "humanoid-ant")
"""The main table's rows: where transfer works first."""
EQ10 = (("reacher", "quick"), ("humanoid-ant", "quick"), ("humanoid-ant", "paper"))
"""The Eq. 10 reruns of PVED: ``<pair>-<budget>-eq10`` beside ``<pair>-<budget>``."""


class Records:
    """The committed records under ``root``/docs/protocol, read once and judged with one
    resampling (``reps``, ``seed``); every verdict a table prints is noted in
    ``verdicts`` (label: verdict)."""

    def __init__(self, root: Path, reps: int = REPS, seed: int = SEED) -> None:
        self.root = Path(root)
        self.reps, self.seed = reps, seed
        self.verdicts: dict[str, str] = {}
        self._judges: dict[tuple[str, ...], tuple[dict[str, PairSummary], Judge]] = {}
        self._claims: dict[str, dict[str, Any]] = {}

    def path(self, name: str) -> Path:
        """A record directory by its name under docs/protocol."""
        return self.root / RECORDS / name

    def judge(self, *inputs: str) -> tuple[dict[str, PairSummary], Judge]:
        """The pairs of record directories ``inputs`` (``DIR`` or ``METHOD=DIR``, as
        ``pved scoreboard`` takes them) and one judge over them."""
        if inputs not in self._judges:
            paths = [
                f"{m}={self.path(d)}" if m else str(self.path(d))
                for m, _, d in (i.rpartition("=") for i in inputs)
            ]
            pairs = load_merged(paths)
            self._judges[inputs] = (pairs, Judge(pairs, reps=self.reps, seed=self.seed))
        return self._judges[inputs]

    def claims(self, budget: str) -> dict[str, Any]:
        """The paper's claims on ``budget``'s records (:data:`BUDGETS`), part by part and
        family-wise, as ``pved claims`` judges them (its claims and Holm; not the
        transfer measures it adds, which no table here prints)."""
        if budget not in self._claims:
            pairs = load_pairs([self.path(d) for d in BUDGETS[budget]])
            judge = Judge(pairs, reps=self.reps, seed=self.seed)
            claims: list[dict[str, Any]] = []
            for paper_claim in PAPER_CLAIMS:
                parts = paper_claim.parts(judge)
                verdict = combine([p["verdict"] for p in parts])
                claims.append({"claim": paper_claim.number, "verdict": verdict, "parts": parts})
            family_wise(claims)
            for judged in claims:
                for part in judged["parts"]:
                    label = f"claims {budget}: {part['part']} on {part['pair']}"
                    self.note(label, part["verdict"])
                    self.note(f"{label} (Holm)", part["family_verdict"])
            self._claims[budget] = {"claims": claims}
        return self._claims[budget]

    def note(self, label: str, verdict: str) -> str:
        """Note a printed verdict under ``label``; returns it."""
        self.verdicts[label] = verdict
        return verdict


# ---------------------------------------------------------------------------- numbers


def _n(x: float, digits: int = 3) -> str:
    """A number as the tables print it, with a true minus sign."""
    return f"{x:.{digits}f}".replace("-", "−")


def _s(x: float) -> str:
    """A signed difference, 3 decimals."""
    return f"{x:+.3f}".replace("-", "−")


def _c(x: float, signed: bool = True) -> str:
    """A compact number for the claims tables: 2 decimals below 10, 1 above."""
    digits = 2 if abs(x) < 10 else 1
    return (f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}").replace("-", "−")


def _ci(ci: Sequence[float], fmt: Callable[[float], str] = _n) -> str:
    return f"[{fmt(ci[0])}, {fmt(ci[1])}]"


def _mean_cell(mean: dict[str, Any] | str) -> str:
    """A method's mean [its own 95% interval], or – where it has no runs."""
    if isinstance(mean, str):
        return "–"
    return f"{_n(mean['mean'])} {_ci(mean['mean_ci'])}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _title(pair: str) -> str:
    return PAIR_TITLES.get(pair, pair).split(" (")[0]


def _unit(metric: str) -> str:
    return UNITS.get(metric, metric)


def _link(page: str, target: str) -> str:
    """``target`` (a path from the repository root) as a link from ``page``."""
    return Path(os.path.relpath(target, Path(page).parent)).as_posix()


def _beats(rec: Records, judge: Judge, pair: str, method: str, label: str) -> str:
    """The verdict of ``method`` beats PPO on ``pair``, noted under ``label``."""
    return rec.note(label, judge.beats(pair, method, "ppo")["verdict"])


# ---------------------------------------------------------------------------- tables


def intervals_line(rec: Records, page: str) -> str:
    """How every interval on the page is made, said once."""
    return (
        f"95% intervals: two-level bootstrap over source policies and seeds, {rec.reps:,} "
        f"resamples, seed {rec.seed} (IQM: one-level, over runs); tables generated from "
        "`docs/protocol/` by `pved publish`."
    )


def _claims_on_pair(result: dict[str, Any], pair: str) -> str:
    """Which claims the parts on ``pair`` decide: "1, 2 hold; 4, 6 do not", and those Holm
    leaves undecided."""
    holds, fails, lost = [], [], []
    for claim in result["claims"]:
        parts = [p for p in claim["parts"] if p["pair"] == pair]
        if not parts:
            continue
        verdict = combine([p["verdict"] for p in parts])
        family = combine([p["family_verdict"] for p in parts])
        number = str(claim["claim"])
        if verdict == HOLDS:
            holds.append(number)
        elif verdict == NOT_HOLD:
            fails.append(number)
        if verdict != UNDECIDED and family != verdict:
            lost.append(number)
    out = []
    if holds:
        out.append(f"{', '.join(holds)} hold{'s' if len(holds) == 1 else ''}")
    if fails:
        out.append(f"{', '.join(fails)} do{'es' if len(fails) == 1 else ''} not")
    text = "; ".join(out) or "none decided"
    if lost and len(lost) == len(holds) + len(fails):
        text += " (not under Holm)"
    elif lost:
        text += f" ({', '.join(lost)} not under Holm)"
    return text


def paper_budget(rec: Records, page: str) -> str:
    """The paper's budget on the four pairs: PPO, PVED, the best of the other methods
    and the oracle, and which of the paper's claims the pair decides."""
    claims = rec.claims("paper")
    rows = []
    for pair in PAPER_ORDER:
        pairs, judge = rec.judge(f"{pair}-paper")
        metric = pairs[pair].metric

        def cell(method: str, pair: str = pair, judge: Judge = judge) -> str:
            text = _mean_cell(judge.mean(pair, method))
            label = f"paper: {method} beats ppo on {pair}"
            if method != "ppo" and _beats(rec, judge, pair, method, label) == HOLDS:
                text = f"**{text}**"
            return text

        means = {m: judge.mean(pair, m) for m in OTHERS}
        best = max(
            (m for m, v in means.items() if isinstance(v, dict)),
            key=lambda m: means[m]["mean"],  # type: ignore[index]
        )
        link = _link(page, f"docs/results/{pair}.md")
        rows.append(
            [
                f"[{_title(pair)}]({link}) ({_unit(metric)})",
                cell("ppo"),
                cell("pved"),
                f"{SHORT[best]} {cell(best)}",
                cell("oracle"),
                _claims_on_pair(claims, pair),
            ]
        )
    header = ["pair (metric)", "PPO", "PVED", "best other method", "oracle"]
    return _table([*header, "the paper's claims on this pair"], rows)


def claims_line(rec: Records, page: str, budget: str) -> str:
    """One sentence: which claims hold, do not hold and are undecided over the four pairs
    together at ``budget`` (and those Holm leaves undecided)."""
    by: dict[str, list[str]] = {HOLDS: [], NOT_HOLD: [], UNDECIDED: []}
    lost = []
    for claim in rec.claims(budget)["claims"]:
        by[claim["verdict"]].append(str(claim["claim"]))
        if claim["verdict"] != UNDECIDED and claim["family_verdict"] != claim["verdict"]:
            lost.append(str(claim["claim"]))

    def listed(numbers: list[str]) -> str:
        return numbers[0] if len(numbers) == 1 else f"{', '.join(numbers[:-1])} and {numbers[-1]}"

    held = f"claims {listed(by[HOLDS])} hold" if by[HOLDS] else "no claim holds"
    rest = [f"{listed(by[NOT_HOLD])} do not"] if by[NOT_HOLD] else []
    rest += [f"{listed(by[UNDECIDED])} are undecided"] if by[UNDECIDED] else []
    text = f"Over the four pairs together {held}" + (f": {', '.join(rest)}" if rest else "")
    if lost:
        text += f" (family-wise, Holm: {listed(lost)} undecided)"
    return text + "."


def difference_line(rec: Records, page: str, directory: str, a: str, b: str) -> str:
    """One sentence: mean final(``a``) − mean final(``b``) with its interval and p, in
    the one pair of ``directory``."""
    pairs, judge = rec.judge(directory)
    (pair,) = pairs
    d = judge.difference(pair, a, b, "final")
    if isinstance(d, str):
        raise PvedError(f"{directory}: {d}")
    ma, mb = judge.mean(pair, a), judge.mean(pair, b)
    return (
        f"`{directory}`: {a} {_mean_cell(ma)} ({d['a']['runs']} runs), {b} {_mean_cell(mb)} "
        f"({d['b']['runs']} runs); {a} − {b} {_s(d['value'])} {_ci(d['ci'], _s)}, p {d['p']:.2g}."
    )


def _part_cell(part: dict[str, Any] | None) -> str:
    """One claim part on one pair and budget: its verdict (bold where decided), the
    difference or PPO's mean against the bar with its interval, the margin, and the
    family-wise verdict where it differs."""
    if part is None:
        return ""
    verdict = part["verdict"]
    cell = verdict if verdict == UNDECIDED else f"**{verdict}**"
    if "bar" in part:
        ppo = part["groups"][0]
        bar = _c(part["bar"], signed=False)
        unsigned = _ci(ppo["mean_ci"], lambda x: _c(x, signed=False))
        cell += f" (PPO {_c(ppo['mean'], signed=False)} {unsigned}, bar {bar})"
    elif "difference" in part:
        diff = part["difference"]
        cell += f" ({_c(diff['value'])} {_ci(diff['ci'], _c)})"
        if "margin" in part:
            cell += f", margin {_c(part['margin'], signed=False)}"
    elif part.get("reason"):
        cell += f" ({part['reason']})"
    if part["family_verdict"] != verdict:
        cell += f"; Holm: {part['family_verdict']}"
    return cell


def _parts(rec: Records, budget: str) -> dict[tuple[int, str], dict[str, dict[str, Any]]]:
    """(claim, part) -> pair -> the part, at ``budget``."""
    rows: dict[tuple[int, str], dict[str, dict[str, Any]]] = {}
    for claim in rec.claims(budget)["claims"]:
        for part in claim["parts"]:
            rows.setdefault((claim["claim"], part["part"]), {})[part["pair"]] = part
    return rows


def claims_matrix(rec: Records, page: str) -> str:
    """Every part of every claim by pair, at the ``quick`` and the ``paper`` budget."""
    budgets = ("quick", "paper")
    by_budget = {b: _parts(rec, b) for b in budgets}
    keys = list(dict.fromkeys([*by_budget["quick"], *by_budget["paper"]]))
    header = ["claim", "part", *(f"{p}, `{b}`" for p in FOUR for b in budgets)]
    rows = [
        [
            str(number),
            name,
            *(
                _part_cell(by_budget[b].get((number, name), {}).get(p))
                for p in FOUR
                for b in budgets
            ),
        ]
        for number, name in keys
    ]
    return _table(header, rows)


def claims_by_budget(rec: Records, page: str) -> str:
    """Each claim's verdict at each budget, per part / family-wise (Holm)."""
    budgets = tuple(BUDGETS)
    results = {b: {c["claim"]: c for c in rec.claims(b)["claims"]} for b in budgets}
    rows = []
    for number, name in CLAIM_NAMES.items():
        cells = []
        for b in budgets:
            claim = results[b][number]
            verdicts = rec.note(f"claims {b}: claim {number}", claim["verdict"])
            family = rec.note(f"claims {b}: claim {number} (Holm)", claim["family_verdict"])
            cells.append(f"{verdicts} / {family}")
        rows.append([name, *cells])
    header = ["claim", "`quick`", "`paper`", "`paper-wide` (reacher, PVED and PPO only)"]
    return _table(header, rows)


def _difference_cell(beats: dict[str, Any]) -> str:
    if "difference" not in beats:
        return "–"
    d = beats["difference"]
    return f"{_s(d['value'])} {_ci(d['ci'], _s)}, p {beats['p']:.2g}"


def eq10_reruns(rec: Records, page: str) -> str:
    """PVED remade after the Eq. 10 fixes against PPO, beside the runs before the fixes."""
    rows = []
    for pair, budget in EQ10:
        after = rec.judge(f"{pair}-{budget}-eq10")[1]
        before = rec.judge(f"{pair}-{budget}")[1]
        beats = after.beats(pair, "pved", "ppo")
        old = before.beats(pair, "pved", "ppo")
        rows.append(
            [
                f"{pair}, `{budget}`",
                _mean_cell(after.mean(pair, "pved")),
                _mean_cell(after.mean(pair, "ppo")),
                _difference_cell(beats),
                rec.note(f"eq10 {budget}: pved beats ppo on {pair}", beats["verdict"]),
                f"{_mean_cell(before.mean(pair, 'pved'))}; {_difference_cell(old)}",
            ]
        )
    header = ["pair, budget", "PVED", "PPO", "PVED − PPO [95% CI], p", "PVED beats PPO"]
    return _table([*header, "before the fixes: PVED; − PPO"], rows)


def _standing(rec: Records, label: str, row: dict[str, Any]) -> str:
    return rec.note(label, row["standing"])


def _steps(row: dict[str, Any]) -> str:
    """Where the method's mean curve reaches PPO's final, as a fraction of PPO's steps."""
    if not row["ppo_improved"]:
        return "first evaluation (PPO did not improve)"
    if row["fraction_of_ppo_steps"] is None:
        return "not reached"
    return f"{row['fraction_of_ppo_steps']:.2f} of PPO's"


def align_paper(rec: Records, page: str, *only: str) -> str:
    """Issue 51 at the paper's budget: ``pved-align`` and ``pved-align-short`` against
    PPO, beside PVED and the oracle (on the pairs ``only``, default all)."""
    methods = ("pved-align", "pved-align-short")
    rows = []
    for pair, inputs in ALIGN_PAPER.items():
        if only and pair not in only:
            continue
        pairs, judge = rec.judge(*inputs)
        metric = pairs[pair].metric
        pved = _mean_cell(judge.mean(pair, "pved"))
        if any(i.startswith("pved=") and i.endswith("-eq10") for i in inputs):
            pved += " (Eq. 10 rerun)"
        cells, steps = [], []
        for method in methods:
            row = pair_row(pairs, pair, method, judge)
            if "reason" in row:
                cells.append("not run")
                continue
            standing = _standing(rec, f"paper: {method} against ppo on {pair}", row)
            d = row["difference"]
            text = f"{_s(d['value'])} {_ci(d['ci'], _s)}"
            own = _mean_cell(judge.mean(pair, method))
            if standing == AHEAD:
                own, text = f"**{own}**", f"**{text}**"
            cells.append(f"{own}; − PPO {text}: {standing}")
            steps.append(f"{SHORT[method]}: {_steps(row)}")
        rows.append(
            [
                f"{pair} ({_unit(metric)})",
                _mean_cell(judge.mean(pair, "ppo")),
                pved,
                *cells,
                _mean_cell(judge.mean(pair, "oracle")),
                ", ".join(steps),
            ]
        )
    header = ["pair (metric)", "PPO", "PVED", "`pved-align`", "`pved-align-short`", "oracle"]
    return _table([*header, "steps to PPO's final"], rows)


def screens_quick(rec: Records, page: str) -> str:
    """Issue 51's screens at the ``quick`` budget: each method against PPO on its pair
    (PPO's cell printed where it differs from the row above's)."""
    rows = []
    last: tuple[str, str] | None = None
    for pair, method, directory in SCREENS:
        pairs, judge = rec.judge(directory)
        row = pair_row(pairs, pair, method, judge)
        if "reason" in row:
            raise PvedError(f"{directory}: {row['reason']}")
        ppo = _mean_cell(judge.mean(pair, "ppo"))
        shown = (pair, ppo)
        first = last is None or last[0] != pair
        standing = _standing(rec, f"quick: {method} against ppo on {pair}", row)
        d = row["difference"]
        diff = f"{_s(d['value'])} {_ci(d['ci'], _s)}"
        if standing == AHEAD:
            diff = f"**{diff}**"
        rows.append(
            [
                f"{pair} ({_unit(pairs[pair].metric)})" if first else "",
                ppo if shown != last else "",
                f"`{method}`",
                _mean_cell(judge.mean(pair, method)),
                f"{diff}, p {d['p']:.2g}",
                standing,
                _steps(row),
            ]
        )
        last = shown
    header = ["pair (metric)", "PPO", "method", "its final", "− PPO [95% CI], p", "standing"]
    return _table([*header, "steps to PPO's final"], rows)


def screens_64(rec: Records, page: str) -> str:
    """Issue 64's screens: each candidate against PPO on its pair by the final score and
    the normalised area under the learning curve (Taylor & Stone's measures,
    :mod:`pved.analysis.transfer_measures`), each beside the pair's A/A gap (ppo-aa − ppo)."""
    rows = []
    for pair, method, directory in SCREENS_64:
        pairs, judge = rec.judge(directory)
        cells = method_measures({pair: pairs[pair]}, method, judge)["pairs"][pair]
        entry = pairs[pair].methods[method]
        chosen_by = "area" if pairs[pair].budget == "screen-auc" else "final"
        line = [
            f"{pair} ({_unit(pairs[pair].metric)})",
            f"`{method}`",
            f"[{directory}]({_link(page, f'{RECORDS}/{directory}/summary.md')})",
            f"{'–' if entry.get('beta') is None else format(entry['beta'], 'g')}, "
            f"{entry.get('init', '–')} ({chosen_by})",
        ]
        for measure in ("final", "auc"):
            c = cells[measure]
            if "reason" in c:
                raise PvedError(f"{directory}: {measure}: {c['reason']}")
            aa = c["aa"]
            diff = f"{_s(c['value'])} {_ci(c['ci'], _s)}"
            ahead = c["ci"][0] > 0 and not c["inside_aa"]
            verdict = rec.note(
                f"screen: {method} against ppo on {pair} ({measure})",
                AHEAD if ahead else ("behind" if c["ci"][1] < 0 else "level"),
            )
            flag = f"; {INSIDE_AA}" if c["inside_aa"] else ""
            aa_text = aa if isinstance(aa, str) else f"{_s(aa['value'])} {_ci(aa['ci'], _s)}"
            line += [
                f"{_n(c['method_mean'])} vs {_n(c['ppo_mean'])}",
                f"**{diff}**" if ahead else diff,
                f"{aa_text}{flag}",
                verdict,
            ]
        rows.append(line)
    header = ["pair (metric)", "method", "record", "β, init (chosen by)"]
    for measure in ("final", "area under the curve"):
        header += [f"{measure}: method vs PPO", "− PPO [95% CI]", "A/A gap", "standing"]
    return _table(header, rows)


def goal_64(rec: Records, page: str, method: str, *directories: str) -> str:
    """Issue 64's goal for ``method`` over the record ``directories`` (one a pair, or
    ``METHOD=DIR``), as ``pved scoreboard --method METHOD DIR...`` prints it: the verdict
    and the table of by how much on each pair (:mod:`pved.analysis.transfer_goal`),
    without the scoreboard's heading."""
    pairs, judge = rec.judge(*directories)
    measures = method_measures(pairs, method, judge)
    goal = transfer_goal(pairs, method, measures, rec.reps, rec.seed)
    rec.note(f"issue 64's goal: {method} over {', '.join(directories)}", goal["verdict"])
    return transfer_goal_markdown(method, goal).split("\n", 2)[2]  # past heading and blank


def pair_verdicts(rec: Records, page: str, pair: str) -> str:
    """The parts of the paper's claims on one pair, at ``quick`` and ``paper``."""
    budgets = ("quick", "paper")
    by_budget = {b: _parts(rec, b) for b in budgets}
    keys = [k for k in dict.fromkeys([*by_budget["quick"], *by_budget["paper"]])]
    rows = [
        [str(n), name, *(_part_cell(by_budget[b].get((n, name), {}).get(pair)) for b in budgets)]
        for n, name in keys
        if any(pair in by_budget[b].get((n, name), {}) for b in budgets)
    ]
    header = ["claim", "part", "`quick` (300k steps a run)", "`paper` (1M steps a run)"]
    return _table(header, rows)


def finals(rec: Records, page: str, directory: str) -> str:
    """Every method's final score in one protocol directory: runs, mean with its own
    interval, the record's IQM with its one-level interval, β and the model init."""
    pairs, judge = rec.judge(directory)
    rows = []
    for pair, summary in pairs.items():
        for method, entry in summary.methods.items():
            final = entry.get("final") or {}
            iqm = "–"
            if "iqm" in final and "iqm_ci" in final:
                iqm = f"{_n(final['iqm'])} {_ci(final['iqm_ci'])}"
            beta, init = entry.get("beta"), entry.get("init")
            rows.append(
                [
                    method,
                    f"{entry.get('runs_finished', '?')}/{entry.get('runs_planned', '?')}",
                    _mean_cell(judge.mean(pair, method)),
                    iqm,
                    "–" if beta is None else f"{beta:g}",
                    "–" if init is None else str(init),
                ]
            )
    header = ["method", "runs", "mean [95% CI]", "IQM [95% CI, one-level]", "beta", "init"]
    return _table(header, rows)


def power(rec: Records, page: str, *inputs: str) -> str:
    """The gain over PPO the two-level verdicts find at 80% power, by source count, from
    the pilot runs of ``inputs`` (:mod:`pved.analysis.power`): ``DIR`` takes every shaped
    method of the record as a pilot, ``METHOD=DIR`` that one (as ``pved scoreboard``
    reads its inputs; PPO's runs come from DIR either way). A first input ``runs=N``
    sets the runs a method (default :data:`RUNS`, paper-45's; the ``paper`` budget's
    15 on walker-hopper and humanoid-ant), split among the source counts of
    :data:`SOURCES` that divide it. A row costs a few seconds of simulation."""
    runs = RUNS
    if inputs and inputs[0].startswith("runs="):
        runs, inputs = int(inputs[0].removeprefix("runs=")), inputs[1:]
    sources = [k for k in SOURCES if runs % k == 0]
    rows = []
    for method, _, directory in (i.rpartition("=") for i in inputs):
        pairs = load_pairs([rec.path(directory)])
        rows += power_rows(pairs, runs, sources, methods=[method] if method else None)
    return power_table(rows)


TABLES: dict[str, Callable[..., str]] = {
    "intervals": intervals_line,
    "claims-line": claims_line,
    "difference": difference_line,
    "paper-budget": paper_budget,
    "claims-matrix": claims_matrix,
    "claims-by-budget": claims_by_budget,
    "eq10-reruns": eq10_reruns,
    "align-paper": align_paper,
    "screens-quick": screens_quick,
    "screens-64": screens_64,
    "goal-64": goal_64,
    "verdicts": pair_verdicts,
    "finals": finals,
    "power": power,
}
"""The tables a marker can name: NAME -> a function of (records, page, *ARGS)."""
