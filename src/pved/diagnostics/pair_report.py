"""One self-contained HTML report per agent pair (``pved report --pair PAIR DIR...``).

The other verbs each write their own output: ``pved protocol`` a protocol directory,
``pved report`` (runs mode) a transfer-report folder, ``pved tsne`` its figures and
``numbers.json``, ``pved video`` GIFs or MP4s, ``pved bound`` a printed summary. This module
gathers whichever of them are given into one HTML file that carries every image and video
inside it as a base64 ``data:`` URI, so it can be mailed or attached to an issue as it is.

Inputs are recognised by what they contain (see :func:`build_pair_report`); an input of
another pair or one that is not a pved output raises :class:`PvedError` naming the file,
before anything is written.

One module past 600 lines on purpose: it makes one HTML page, each section a short
reader of one verb's output kept beside the others so that the page stays one document.
"""

from __future__ import annotations

import base64
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Any

from pved import __version__
from pved.analysis.curves import reach_cell
from pved.checks import check_writable
from pved.envs.registry import env_id
from pved.errors import PvedError
from pved.record_paths import resolve_record_path
from pved.runs import atomic_write_bytes, read_json
from pved.spec import get_preset

VIDEO_SUFFIXES = (".gif", ".mp4", ".webm")
# the rollouts rendered for a protocol's methods: long enough to see the gait or the
# insertion, small enough to keep a report of 8 methods a few MB
VIDEO_MAX_STEPS = 300
VIDEO_SIZE = 160
# Keys a bound JSON must have: those of pved.diagnostics.bound.BoundResult the report shows.
BOUND_KEYS = ("delta", "quantile", "a", "b", "m", "bound", "gap", "held")
EXPECTED = (
    "expected a protocol directory (protocol.json + summary.json), a transfer-report "
    "directory (results.json), a t-SNE directory (numbers.json or tsne_shared.png), a bound "
    "file (bound*.json / the line `pved bound` prints) or .gif/.mp4/.webm videos"
)
# MIME type and leading bytes of every embedded file: a truncated or mislabelled file is
# refused with its name instead of becoming a broken picture in the report.
_MEDIA: dict[str, tuple[str, tuple[tuple[int, bytes], ...]]] = {
    ".png": ("image/png", ((0, b"\x89PNG\r\n\x1a\n"),)),
    ".gif": ("image/gif", ((0, b"GIF87a"), (0, b"GIF89a"))),
    ".mp4": ("video/mp4", ((4, b"ftyp"),)),
    ".webm": ("video/webm", ((0, b"\x1a\x45\xdf\xa3"),)),
}
# The line ``pved bound`` prints (BoundResult.summary), for bound files saved with
# ``pved bound ... > bound.txt``; the verb writes no JSON of its own.
_NUM = r"[-+]?(?:inf|nan|\d+(?:\.\d*)?(?:e[-+]?\d+)?)"
_COROLLARY = (
    rf"Corollary 1 \(gamma=(?P<gamma>{_NUM})\): "
    rf"bound (?P<return_bound>{_NUM}) "
    rf"\(finite n=(?P<horizon>\d+): (?P<return_bound_finite>{_NUM})\) "
    rf"vs return gap (?P<return_gap>{_NUM}) \((?P<return_held>held|VIOLATED)\)"
)
_BOUND_LINE = re.compile(
    rf"Theorem 1: delta=max KL=(?P<delta>{_NUM}) \(q(?P<quantile>{_NUM}) "
    rf"(?P<delta_quantile>{_NUM}), mean (?P<kl_mean>{_NUM})\), "
    rf"\[a,b\]=\[(?P<a>{_NUM}),(?P<b>{_NUM})\], m=(?P<m>{_NUM}) -> "
    rf"bound (?P<bound>{_NUM})(?P<vacuous> \(vacuous: sqrt\(2 delta\) >= 2\))? "
    rf"vs gap (?P<gap>{_NUM}) \((?P<held>held|VIOLATED)\); with the q{_NUM} KL in place "
    rf"of delta (?P<bound_quantile>{_NUM}) \(typical pairs, not the theorem's bound\); "
    + _COROLLARY
)
# The line as printed before 2026-12-05, when delta was a quantile of the KL (bound.txt
# files of the protocols published then): read as such, and shown as such.
_BOUND_LINE_QUANTILE = re.compile(
    rf"Theorem 1: delta\(q(?P<quantile>{_NUM})\)=(?P<delta_quantile>{_NUM}) "
    rf"\(KL max (?P<kl_max>{_NUM})\), \[a,b\]=\[(?P<a>{_NUM}),(?P<b>{_NUM})\], "
    rf"m=(?P<m>{_NUM}) -> bound (?P<bound_quantile>{_NUM}) vs gap (?P<gap>{_NUM}) "
    rf"\((?P<held_quantile>held|VIOLATED)\); " + _COROLLARY
)
# Sets data-images-loaded / data-images-total on <body> once the page has loaded, so a
# headless browser (``chromium --dump-dom``) can check that every embedded image decodes.
_IMAGE_CHECK = (
    "window.addEventListener('load', function () {"
    " var imgs = document.images, ok = 0;"
    " for (var i = 0; i < imgs.length; i++) {"
    " if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok++; } }"
    " document.body.dataset.imagesLoaded = String(ok);"
    " document.body.dataset.imagesTotal = String(imgs.length); });"
)
# Everything must come from the page itself: the browser refuses any other source.
_CSP = (
    "default-src 'none'; img-src data:; media-src data:; "
    "style-src 'unsafe-inline'; script-src 'unsafe-inline'"
)
_CSS = """
body { font-family: sans-serif; max-width: 70em; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.4; }
h1 { margin-bottom: 0.2em; }
table { border-collapse: collapse; margin: 0.8em 0; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
figure { display: inline-block; margin: 0.5em 1em 0.5em 0; vertical-align: top; }
figure img, figure video { max-width: 100%; border: 1px solid #ddd; }
figcaption, .note { color: #555; font-size: 0.9em; }
.missing { background: #fff6d5; padding: 0.5em; border-left: 4px solid #e0b000; }
"""


@dataclass
class _Parts:
    """What the inputs gave, section by section, in input order."""

    inputs: list[str] = field(default_factory=list)
    curves: list[tuple[str, Path]] = field(default_factory=list)  # (caption, PNG)
    tables: list[str] = field(default_factory=list)  # rendered HTML
    tsne: list[tuple[str, Path]] = field(default_factory=list)  # (caption, PNG)
    numbers: list[tuple[Path, dict[str, Any]]] = field(default_factory=list)
    bounds: list[tuple[Path, dict[str, Any], bool]] = field(default_factory=list)  # parsed?
    videos: list[tuple[str, Path]] = field(default_factory=list)  # (caption, file)
    render_videos: bool = True  # a protocol input gets one rendered rollout per method


# ---------------------------------------------------------------------- small helpers
def _fmt(value: Any, digits: int = 3) -> str:
    """A table cell: fixed decimals for floats, '–' for missing or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _sig(value: Any) -> str:
    """Four significant digits (the bound's quantities span many magnitudes)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return _fmt(value)
    return f"{value:.4g}"


def _with_ci(mean: Any, ci: Any, digits: int = 3) -> str:
    """``mean [lo, hi]`` for a bootstrap interval; ``mean ± h`` for the half-widths that
    transfer reports written before the bootstrap (e.g. reports/reacher-1m) hold."""
    if mean is None:
        return "–"
    if isinstance(ci, list | tuple) and len(ci) == 2:
        return f"{_fmt(mean, digits)} [{_fmt(ci[0], digits)}, {_fmt(ci[1], digits)}]"
    if isinstance(ci, int | float):
        return f"{_fmt(mean, digits)} ± {_fmt(float(ci), digits)}"
    return _fmt(mean, digits)


def _table(
    header: Sequence[str], rows: Sequence[Sequence[str]], text_columns: Sequence[int] = (0,)
) -> str:
    """An HTML table of already formatted cells (escaped here); all columns but
    ``text_columns`` hold numbers and are right-aligned."""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = []
    for row in rows:
        cells = "".join(
            f"<td>{escape(c)}</td>" if i in text_columns else f'<td class="num">{escape(c)}</td>'
            for i, c in enumerate(row)
        )
        body.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _data_uri(path: Path) -> tuple[str, str]:
    """``(mime, data URI)`` of a PNG/GIF/MP4/WebM file, after checking its leading bytes."""
    suffix = path.suffix.lower()
    if suffix not in _MEDIA:
        raise PvedError(f"{path}: cannot embed {suffix or 'a file without suffix'}")
    mime, signatures = _MEDIA[suffix]
    try:
        data = path.read_bytes()
    except OSError as err:
        raise PvedError(f"cannot read {path} ({err.strerror})") from None
    if not any(data[off : off + len(sig)] == sig for off, sig in signatures):
        raise PvedError(f"{path} is not a valid {suffix[1:].upper()} file")
    return mime, f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _figure(path: Path, caption: str) -> str:
    mime, uri = _data_uri(path)
    if mime.startswith("video/"):
        media = f'<video controls preload="metadata" src="{uri}"></video>'
    else:
        media = f'<img src="{uri}" alt="{escape(caption, quote=True)}">'
    return f"<figure>{media}<figcaption>{escape(caption)}</figcaption></figure>"


# ----------------------------------------------------------------------- recognisers
def _add_protocol(pair: str, directory: Path, parts: _Parts) -> None:
    """A ``pved protocol`` output: curves-<pair>.png and the summary.json table."""
    plan_file = directory / "protocol.json"
    plan = read_json(plan_file)
    pairs = plan.get("pairs") if isinstance(plan, dict) else None
    if not isinstance(pairs, list):
        raise PvedError(f"{plan_file} is not a pved protocol plan (no list of pairs)")
    if pair not in pairs:
        raise PvedError(f"{plan_file} is for pair(s) {', '.join(map(str, pairs))}, not {pair!r}")
    summary_file = directory / "summary.json"
    if not summary_file.is_file():
        raise PvedError(f"{directory} has no summary.json yet; `pved plot {directory}` writes it")
    summary = read_json(summary_file)
    try:
        info = summary["pairs"][pair]
        metric, methods = info["metric"], info["methods"]
    except (KeyError, TypeError):
        raise PvedError(f"{summary_file} has no results for pair {pair!r}") from None
    parts.inputs.append(f"protocol: {directory}")
    curves = directory / f"curves-{pair}.png"
    if not curves.is_file() and pairs == [pair]:  # older protocol dirs: one combined figure
        curves = directory / "curves.png"
    if curves.is_file():
        what = metric.replace("_", " ")
        parts.curves.append((f"protocol {directory.name}: {what} per method", curves))
    rows = []
    for method, m in methods.items():
        final = m.get("final") or {}
        rows.append(
            [
                str(method),
                f"{m.get('runs_finished', '–')}/{m.get('runs_planned', '–')}",
                _with_ci(final.get("mean"), final.get("mean_ci")),
                _with_ci(final.get("iqm"), final.get("iqm_ci")),
                reach_cell(m, "ppo"),
                reach_cell(m, "oracle"),
                _sig(m.get("beta")),
                _fmt(m.get("init")),
            ]
        )
    budget, label = summary.get("budget", "?"), metric.replace("_", " ")
    notes = [
        f"Protocol {directory} ({budget} budget): final {label} over the evaluation runs, "
        "the mean with its 95% CI as the summary records it (the two-level bootstrap over "
        "source policies and seeds since 2026-12-06; one-level, over runs, before), the "
        "interquartile mean (IQM) with a one-level 95% CI (rliable); "
        "'steps to PPO's final' (the oracle's) is the env steps a method's mean curve needs "
        "to reach the last point of plain PPO's (the oracle's) mean curve."
    ]
    failed, blocked = len(summary.get("failed") or {}), len(summary.get("blocked") or [])
    if failed or blocked:
        notes.append(f"{failed} runs failed and {blocked} were blocked (see {summary_file}).")
    header = ["method", "runs", f"final {label}: mean [95% CI]", "IQM [95% CI, one-level]"]
    header += ["steps to PPO's final", "steps to the oracle's final", "β", "init"]
    parts.tables.append(f'<p class="note">{escape(" ".join(notes))}</p>' + _table(header, rows))
    if parts.render_videos:
        _add_method_videos(pair, directory, methods, parts)


def _add_method_videos(
    pair: str, directory: Path, methods: Mapping[str, Any], parts: _Parts
) -> None:
    """One rollout per method: the policy of its first evaluation run on the target
    task, rendered once into ``<protocol>/videos/<method>.gif`` and reused after."""
    from pved.diagnostics.video import render_rollout

    preset = get_preset(pair)
    env = env_id(preset.target_agent, preset.target_task)
    for method, m in methods.items():
        runs = m.get("runs") or []
        if not runs or not runs[0].get("result"):
            continue
        policy = resolve_record_path(runs[0]["result"], directory).parent / "policy.pt"
        if not policy.is_file():
            continue
        out = directory / "videos" / f"{method}.gif"
        if not out.is_file():
            render_rollout(
                policy, env, out, seed=0, max_steps=VIDEO_MAX_STEPS,
                width=VIDEO_SIZE, height=VIDEO_SIZE,
            )  # fmt: skip
        caption = f"{method}: its first evaluation run ({runs[0].get('key', '')}) on {env}"
        _add_video(out, caption, parts)


def _add_transfer_report(pair: str, directory: Path, parts: _Parts) -> None:
    """A runs-mode ``pved report`` folder: curves_*.png and the results.json table."""
    results_file = directory / "results.json"
    results = read_json(results_file)
    if not isinstance(results, dict) or not isinstance(results.get("rows"), list):
        raise PvedError(f"{results_file} is not a pved transfer report (no rows)")
    if "pair" in results and results["pair"] != pair:
        raise PvedError(f"{results_file} is for pair {results['pair']!r}, not {pair!r}")
    metric = str(results.get("metric", "success_rate"))
    label = metric.replace("_", " ")
    parts.inputs.append(f"transfer report: {directory}")
    pngs = sorted(directory.glob("curves_*.png"), key=lambda p: (p.stem != f"curves_{metric}", p))
    for png in pngs:
        what = png.stem.removeprefix("curves_").replace("_", " ")
        parts.curves.append((f"transfer report {directory.name}: {what}", png))
    has_iqm = any("final_iqm" in r for r in results["rows"] if isinstance(r, dict))
    rows = []
    for r in results["rows"]:
        if not isinstance(r, dict) or "method" not in r:
            raise PvedError(f"{results_file} has a row without a method")
        per_seed = r.get(f"final_{metric}") or []
        row = [
            str(r["method"]),
            _fmt(len(r.get("seeds") or per_seed)),
            _fmt(r.get("steps")),
            _with_ci(r.get("final_mean"), r.get("final_ci95")),
        ]
        if has_iqm:
            row.append(_with_ci(r.get("final_iqm"), r.get("final_iqm_ci95")))
        row += [
            " ".join(_fmt(float(v), 2) for v in per_seed),  # non-numbers: caught in _collect
            _with_ci(r.get("curve_mean"), r.get("curve_ci95")),
            _with_ci(r.get("final_return_mean"), r.get("final_return_ci95"), 2),
        ]
        rows.append(row)
    header = ["method", "seeds", "env steps", f"final {label}: mean [95% CI]"]
    header += ["IQM [95% CI, one-level]"] if has_iqm else []
    header += ["per seed", "curve mean [95% CI]", "final return: mean [95% CI]"]
    ci = results.get("ci95", "± is the 95% t-interval over seeds (report before the bootstrap)")
    note = (
        f"Transfer report {directory}: final {label} on fresh episodes after training; "
        f"'curve mean' is the mean of the evaluation points along training. CI: {ci}."
    )
    parts.tables.append(f'<p class="note">{escape(note)}</p>' + _table(header, rows))


def _add_tsne(directory: Path, parts: _Parts) -> None:
    """A ``pved tsne --out`` folder: the scatters, the mark strips, the x split
    (``fig8_groups.png``, paper Fig. 8) and numbers.json."""
    parts.inputs.append(f"t-SNE: {directory}")
    numbers_file = directory / "numbers.json"
    numbers: Any = None
    if numbers_file.is_file():
        numbers = read_json(numbers_file)
        if not isinstance(numbers, dict) or "shared" not in numbers:
            raise PvedError(f"{numbers_file} is not pved tsne numbers (no 'shared' entry)")
    for name, what in (("tsne_shared", "shared"), ("tsne_individual", "individual")):
        png = directory / f"{name}.png"
        if png.is_file():
            parts.tsne.append((f"t-SNE of the {what} subspace", png))
    marks: list[tuple[int, Path]] = []
    for png in directory.glob("mark_*.png"):
        index = png.stem.removeprefix("mark_")
        if index.isdigit():  # numeric order: mark_10 after mark_9
            marks.append((int(index), png))
    # Strips with later target frames (the paper's Ant, Fig. 7) say so in their caption.
    frames = (numbers or {}).get("mark_frames") or {}
    later, stride = frames.get("target_later_frames", 0), frames.get("later_frame_stride")
    rows = "nearest source (top) and target (bottom) frames"
    if isinstance(later, int) and later > 0:
        rows = (
            f"nearest source (top) and target (second) frames, then {later} later target "
            f"frames {stride} steps apart"
        )
    for j, png in sorted(marks):
        parts.tsne.append((f"mark ({j}): {rows}", png))
    fig8 = directory / "fig8_groups.png"
    if fig8.is_file():
        split = (numbers or {}).get("x_split") or {}
        at = split.get("threshold_m")
        where = f"x = {_fmt(at, 1)} m" if isinstance(at, (int, float)) else "the x threshold"
        parts.tsne.append(
            (
                f"Fig. 8: the target's shared-embedding points in k-means groups, counted "
                f"before and after {where}",
                fig8,
            )
        )
    if numbers is not None:
        parts.numbers.append((numbers_file, numbers))


def _parse_bound(path: Path, pair: str) -> tuple[dict[str, Any], bool] | None:
    """A bound from ``path``: a JSON object with :data:`BOUND_KEYS` (``transferred.bound``'s
    return value or ``BoundResult.as_dict()``), or text holding the line ``pved bound``
    prints. Returns ``(values, parsed_from_text)``, or None when it is neither."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError:
        obj = None
    if isinstance(obj, dict) and all(k in obj for k in BOUND_KEYS):
        if "pair" in obj and obj["pair"] != pair:
            raise PvedError(f"{path} is for pair {obj['pair']!r}, not {pair!r}")
        return obj, False
    match = _BOUND_LINE.search(text) or _BOUND_LINE_QUANTILE.search(text)
    if match is None:
        return None
    flags, ints = ("held", "held_quantile", "return_held"), ("horizon",)
    values: dict[str, Any] = {
        k: v == "held" if k in flags else int(v) if k in ints else float(v)
        for k, v in match.groupdict().items()
        if k != "vacuous"
    }
    if "held_quantile" in values:
        # δ as the theorem has it is the max KL; the old line's bound used a quantile
        delta = max(values["kl_max"], 0.0)
        values.update(
            delta=delta,
            bound=values["m"] + (values["b"] - values["a"]) / 2 * (2 * delta) ** 0.5,
        )
        values["held"] = values["gap"] <= values["bound"]
        values["vacuous"] = (2 * delta) ** 0.5 >= 2
        # Corollary 1 is the same right-hand side times a factor of γ and n alone
        if values["bound_quantile"] > 0:
            factor = values["bound"] / values["bound_quantile"]
            for key in ("return_bound", "return_bound_finite"):
                values[key] *= factor
            values["return_held"] = values["return_gap"] <= values["return_bound_finite"]
        del values["held_quantile"]
    else:
        values["vacuous"] = match.group("vacuous") is not None
    return values, True


def _add_bound_file(pair: str, path: Path, parts: _Parts) -> bool:
    parsed = _parse_bound(path, pair)
    if parsed is None:
        return False
    parts.inputs.append(f"bound: {path}")
    parts.bounds.append((path, *parsed))
    return True


def _add_video(path: Path, caption: str, parts: _Parts) -> None:
    _data_uri(path)  # refuse a broken file now, before anything is written
    parts.videos.append((caption, path))


def _collect(pair: str, inputs: Sequence[Path], render_videos: bool = True) -> _Parts:
    parts = _Parts(render_videos=render_videos)
    for raw in inputs:
        path = Path(raw)
        if not path.exists():
            raise PvedError(f"{path} does not exist")
        try:
            if path.is_dir():
                _collect_dir(pair, path, parts)
            else:
                _collect_file(pair, path, parts)
        except (AttributeError, KeyError, TypeError, ValueError) as err:
            # A file of the right name whose values have the wrong types (hand-edited,
            # another tool's): one line naming the input instead of a traceback.
            what = " ".join(str(err).split())
            raise PvedError(
                f"{path} is not a readable pved output ({type(err).__name__}: {what})"
            ) from None
    return parts


def _collect_dir(pair: str, directory: Path, parts: _Parts) -> None:
    """Every kind of output found in ``directory`` (one folder may hold several)."""
    found = False
    if (directory / "protocol.json").is_file():
        _add_protocol(pair, directory, parts)
        found = True
    if (directory / "results.json").is_file():
        _add_transfer_report(pair, directory, parts)
        found = True
    if (directory / "numbers.json").is_file() or (directory / "tsne_shared.png").is_file():
        _add_tsne(directory, parts)
        found = True
    for candidate in sorted(directory.glob("bound*")):
        if candidate.is_file() and candidate.suffix.lower() in (".json", ".txt"):
            if not _add_bound_file(pair, candidate, parts):
                raise PvedError(f"{candidate} is not a pved bound ({EXPECTED})")
            found = True
    # a protocol's run tree is not searched (thousands of files, no videos), nor are the
    # per-method videos it already added
    added = {p.resolve() for _, p in parts.videos}
    runs = (directory / "runs").resolve() if (directory / "protocol.json").is_file() else None
    videos = sorted(
        p
        for p in directory.rglob("*")
        if p.suffix.lower() in VIDEO_SUFFIXES
        and p.is_file()
        and p.resolve() not in added
        and (runs is None or runs not in p.resolve().parents)
    )
    for video in videos:
        _add_video(video, str(video.relative_to(directory)), parts)
    if videos:
        parts.inputs.append(f"videos: {len(videos)} under {directory}")
        found = True
    if not found:
        raise PvedError(f"{directory} is not a pved output ({EXPECTED})")


def _collect_file(pair: str, path: Path, parts: _Parts) -> None:
    """A single file: a video, a bound, or one of the directories' index files."""
    if path.suffix.lower() in VIDEO_SUFFIXES:
        _add_video(path, path.name, parts)
        parts.inputs.append(f"video: {path}")
    elif path.name in ("protocol.json", "summary.json", "selection.json"):
        _add_protocol(pair, path.parent, parts)
    elif path.name == "results.json":
        _add_transfer_report(pair, path.parent, parts)
    elif path.name == "numbers.json":
        _add_tsne(path.parent, parts)
    elif not _add_bound_file(pair, path, parts):
        raise PvedError(f"{path} is not a pved output ({EXPECTED})")


# ------------------------------------------------------------------------- rendering
def _numbers_section(path: Path, numbers: Mapping[str, Any]) -> str:
    """The correspondence and probe numbers of one numbers.json, one explained row each."""
    chance = numbers.get("chance_time_difference")
    rows: list[list[str]] = []
    for space, want in (("shared", "small"), ("individual", "near chance")):
        sub = numbers.get(space)
        if not isinstance(sub, dict):
            continue
        rows.append(
            [
                f"{space}: time correspondence |Δt|",
                _fmt(sub.get("nn_time_difference")),
                f"mean normalised-time gap between a target step and its nearest source step "
                f"in the {space} subspace ({want} is expected; chance {_fmt(chance)})",
            ]
        )
    rows.append(
        [
            "chance |Δt|",
            _fmt(chance),
            "the gap an uninformative nearest neighbour gives (1/3 for uniform times)",
        ]
    )
    for space, want in (("shared", "≈0.5: the agents overlap"), ("individual", "≈1: separated")):
        sub = numbers.get(space)
        if not isinstance(sub, dict):
            continue
        rows.append(
            [
                f"{space}: agent-probe accuracy",
                _fmt(sub.get("agent_probe_accuracy")),
                f"held-out balanced accuracy of a linear probe for agent identity on the "
                f"{space} posterior means ({want} is expected)",
            ]
        )
    split = numbers.get("x_split")
    if isinstance(split, dict) and isinstance(split.get("groups"), list):
        at = _fmt(split.get("threshold_m"), 1)
        for g, group in enumerate(split["groups"], start=1):
            if not isinstance(group, dict):
                continue
            near = group.get("nearest_mark")
            where = f" (nearest mark ({near}))" if near is not None else ""
            rows.append(
                [
                    f"x split: group G{g}{where} after {at} m",
                    _fmt(group.get("frac_after")),
                    f"fraction of the {group.get('size', '?')} target points of this k-means "
                    f"group of the shared embedding with x ≥ {at} m ({group.get('before', '?')} "
                    f"before, {group.get('after', '?')} after; Fig. 8)",
                ]
            )
        rows.append(
            [
                "x split: range of the fractions",
                _fmt(split.get("frac_after_range")),
                "largest minus smallest fraction after: ≈1 when the groups are the terrain "
                "before and after the threshold (the paper's reading for Ant), ≈0 when "
                "the grouping is unrelated to x",
            ]
        )
    points = numbers.get("num_points") or {}
    success = numbers.get("success_rate") or {}
    note = (
        f"From {path}: {numbers.get('episodes', '?')} episodes per agent, "
        f"{points.get('source', '?')} source and {points.get('target', '?')} target steps; "
        f"success rate source {_fmt(success.get('source'))}, "
        f"target {_fmt(success.get('target'))}."
    )
    table = _table(["number", "value", "what it says"], rows, text_columns=(0, 2))
    return f'<p class="note">{escape(note)}</p>{table}'


def _bound_section(path: Path, b: Mapping[str, Any], from_text: bool) -> str:
    """Theorem 1 (and Corollary 1 where given) beside the measured gaps."""
    rows = [
        ["δ = max KL over the pairs (Theorem 1's hypothesis)", _sig(b["delta"])],
        [f"KL quantile q={_sig(b['quantile'])} (typical pairs, not δ)",
         _sig(b.get("delta_quantile"))],
        ["reward range [a, b]", f"[{_sig(b['a'])}, {_sig(b['b'])}]"],
        ["m = max |r_T − r_S|", _sig(b["m"])],
        ["bound m + (b − a)/2 · √(2δ) (Eq. 13)", _sig(b["bound"])],
        ["vacuous (√(2δ) ≥ 2: no tighter than (b − a) + m)", _fmt(b.get("vacuous"))],
        ["measured gap |mean r_T − mean r_S|", _sig(b["gap"])],
        ["held", _fmt(bool(b["held"]))],
        ["the same with the quantile in place of δ (not a bound)",
         _sig(b.get("bound_quantile"))],
    ]  # fmt: skip
    if "return_bound" in b:
        rows += [
            [f"Corollary 1, γ={_sig(b.get('gamma'))}: return bound (Eq. 14)",
             _sig(b["return_bound"])],
            [f"finite horizon n={_fmt(b.get('horizon'))} (Eq. 26)",
             _sig(b.get("return_bound_finite"))],
            ["measured return gap", _sig(b.get("return_gap"))],
            ["return bound held (finite n)", _fmt(b.get("return_held"))],
        ]  # fmt: skip
    source = f"From {path}" + (
        " (the line `pved bound` prints: 4 significant digits)." if from_text else "."
    )
    if "episodes" in b:
        source += f" {b['episodes']} episodes per agent, {b.get('matched_pairs', '?')} pairs."
    return f'<p class="note">{escape(source)}</p>' + _table(["quantity", "value"], rows)


# (attribute of _Parts, section name, the input that gives it) for the "not given" line
_SECTIONS = (
    ("curves", "learning curves", "a protocol or transfer-report directory"),
    ("tables", "results table", "a protocol or transfer-report directory"),
    ("tsne", "t-SNE figures", "a `pved tsne --out` directory"),
    ("numbers", "correspondence and probe numbers", "its numbers.json"),
    ("bounds", "bound", "the line `pved bound` prints, saved to a file"),
    ("videos", "videos", "`pved video` files"),
)


def _render(pair: str, parts: _Parts) -> str:
    preset = get_preset(pair)
    title = f"pved report: {pair}"
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">',
        f"<title>{escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        "<p>"
        + escape(
            f"{preset.source_agent} → {preset.target_agent}: trained on {preset.training_task}, "
            f"transferred to the target task {preset.target_task} "
            f"(metric: {preset.metric.replace('_', ' ')}). pved {__version__}."
        )
        + "</p>",
        "<ul>" + "".join(f"<li>{escape(i)}</li>" for i in parts.inputs) + "</ul>",
    ]
    missing = [f"{name} (from {hint})" for key, name, hint in _SECTIONS if not getattr(parts, key)]
    if missing:
        out.append(f'<p class="missing">{escape("Not given: " + "; ".join(missing) + ".")}</p>')
    if parts.curves:
        out.append("<h2>Learning curves</h2>")
        out += [_figure(png, caption) for caption, png in parts.curves]
    if parts.tables:
        out.append("<h2>Results</h2>")
        out += parts.tables
    if parts.tsne:
        out.append("<h2>t-SNE of the subspaces, with the nearest frames</h2>")
        out += [_figure(png, caption) for caption, png in parts.tsne]
    if parts.numbers:
        out.append("<h2>Time correspondence and agent probes</h2>")
        out += [_numbers_section(path, numbers) for path, numbers in parts.numbers]
    if parts.bounds:
        out.append("<h2>Theorem 1 bound against the measured gap</h2>")
        out += [_bound_section(path, b, from_text) for path, b, from_text in parts.bounds]
    if parts.videos:
        out.append("<h2>Videos</h2>")
        out += [_figure(video, caption) for caption, video in parts.videos]
    out += [f"<script>{_IMAGE_CHECK}</script>", "</body></html>", ""]
    return "\n".join(out)


def default_report_path(pair: str) -> Path:
    """``reports/<pair>-report.html`` (relative to the working directory)."""
    return Path("reports") / f"{pair}-report.html"


def build_pair_report(
    pair: str, inputs: Sequence[Path], out: Path | None = None, videos: bool = True
) -> Path:
    """Write one self-contained HTML report of ``pair`` from other verbs' outputs.

    Each input is recognised by what it contains (a directory may hold several kinds):

    * protocol directory (``pved protocol``): ``protocol.json`` listing ``pair``, its
      ``summary.json`` (table: mean and IQM with CIs, steps to PPO's and the oracle's
      final, β, init), ``curves-<pair>.png``, and (with ``videos``) one rollout per method
      of the policy of its first evaluation run, rendered once into
      ``videos/<method>.gif`` there;
    * transfer-report directory (``pved report`` without DIRs): ``results.json`` (table)
      and ``curves_*.png``;
    * t-SNE directory (``pved tsne --out``): ``numbers.json`` and/or ``tsne_shared.png``,
      ``tsne_individual.png``, ``mark_<j>.png``;
    * bound: a file (or ``bound*.json`` / ``bound*.txt`` in a directory) holding a JSON
      object with the :class:`pved.diagnostics.bound.BoundResult` fields, or the line
      ``pved bound`` prints;
    * videos: ``.gif``/``.mp4``/``.webm`` files, given or anywhere under a given directory.

    Sections come in the order title, learning curves, results, t-SNE figures, numbers,
    bound, videos; sections no input gave are listed as not given. Every image and video
    is embedded as a base64 ``data:`` URI; the page loads nothing else.

    Args:
        pair: a preset name (``pved list``).
        inputs: the outputs, in the order their items should appear.
        out: the HTML file (default ``reports/<pair>-report.html``); written atomically.
        videos: render the protocol's per-method rollouts (offscreen MuJoCo).

    Returns:
        ``out``.

    Raises:
        PvedError: an input that does not exist, is not a pved output, belongs to another
            pair (``protocol.json`` pairs, ``results.json`` pair) or is corrupt; nothing
            is written then.
    """
    get_preset(pair)  # an unknown pair fails first, with the known ones
    if not inputs:
        raise PvedError("a pair report needs at least one input directory or file")
    path = default_report_path(pair) if out is None else Path(out)
    if path.is_dir():
        path = path / f"{pair}-report.html"
    check_writable("--out", path, directory=False)  # before the videos are rendered
    parts = _collect(pair, inputs, render_videos=videos)
    page = _render(pair, parts)
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
