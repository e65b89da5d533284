"""Running the protocol (:mod:`pved.protocol.plan`, paper IV.A) and
summing it up: ``pved protocol`` and ``pved plot``.

:func:`run_protocol` writes the plan (``protocol.json``), copies another protocol's
finished stages in (``--stages-from``, :func:`copy_stage_runs`), runs the job graph on
Ray or a local pool, and ends with :func:`summarize`, which rebuilds the selection,
``summary.json``/``summary.md`` and the curves from the run files alone.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pved import __version__
from pved.checks import check_int, check_writable
from pved.errors import PvedError
from pved.models.train import shared_subspace_collapsed
from pved.protocol.plan import (
    PLAN_FILE,
    SOURCE_BAR,
    ProtocolPlan,
    finished_results,
    fixed_selections,
    plan_entry,
    relative_plan,
)
from pved.protocol.preregistration import check_gate, mark_summary, write_record
from pved.protocol.runner import RunnerReport, check_reachable, resolve_backend, run_jobs
from pved.provenance import (
    UNKNOWN,
    count_fingerprints,
    fingerprint_of_run,
    pinned_fingerprint,
)
from pved.record_paths import record_path
from pved.rl.ppo import CHECKPOINT_SECONDS
from pved.run_layout import transfer_run_method
from pved.runs import atomic_write_bytes, atomic_write_json, repoint_result, run_path
from pved.transfer.methods import NO_TRANSFER, ORACLE, REFERENCE_METHODS, get_method
from pved.transfer.shaping import GUIDE_FORMS

if TYPE_CHECKING:
    from pved.analysis.curves import Panel


# -- running it -------------------------------------------------------------------------


def _stages_source(source: Path | str, out: Path | str) -> Path:
    """``source`` resolved, once it is known to be another protocol's directory."""
    resolved = Path(source).resolve()
    if not (resolved / PLAN_FILE).is_file():
        raise PvedError(f"--stages-from {source} is not a protocol directory (no {PLAN_FILE})")
    if resolved == Path(out).resolve():
        raise PvedError("--stages-from names the protocol's own directory")
    return resolved


#: The stages whose runs a protocol may take from another one (``--stages-from``): what
#: they compute depends on their own config, not on the budget's steps per transfer run.
COPYABLE_STAGES = ("policy", "pairs", "model", "bank")


@dataclasses.dataclass(frozen=True)
class StageCopy:
    """What :func:`copy_stage_runs` did.

    Attributes:
        copied: runs copied in.
        other_code: finished transfer runs it would have copied but did not, made under
            another numeric fingerprint than this code's, or before runs recorded one.
        fingerprint: this code's fingerprint (:func:`pved.provenance.pinned_fingerprint`).
    """

    copied: int
    other_code: int
    fingerprint: str | None

    def describe(self, source: Path | str) -> str:
        """The protocol's line on the copy: how many came, and how many were passed over."""
        line = f"copied {self.copied} finished runs from {source}"
        if self.other_code:
            line += (
                f"; passed over {self.other_code} finished transfer runs not made under this "
                f"code's numeric fingerprint ({self.fingerprint}): they are made again"
            )
        if self.copied:  # the copy does not know the plan's configs: the runs check them
            line += "; a copied run whose config is not the one this plan asks for is made again"
        return line


def copy_stage_runs(source: Path | str, out: Path | str, pairs: Sequence[str]) -> StageCopy:
    """Copy ``source``'s finished policy, pairs, model and bank runs of ``pairs`` into
    protocol directory ``out`` where ``out`` has no run of that name yet. Where both plans
    give a pair the same steps per transfer run (``paper`` and ``paper-wide``, say), its
    finished transfer runs of the methods ``out``'s plan has are copied too, but only
    those made by code of this code's numeric fingerprint (:mod:`pved.provenance`).

    A copied run is used only where its ``config.json`` hash equals the one the plan of
    ``out`` asks for (``Run.is_done``); any other is redone, as an interrupted run
    would be, so a copy can save hours (a locomotion pair's 18 models) but cannot put a
    run made under other settings into the results. The hash leaves out the code that
    made a run, so a transfer run's fingerprint is checked too: PPO runs copied from an
    older protocol beside ``ppo-aa`` runs made now would put two versions of the code
    into one A/A floor (issue 64: a method is compared with PPO made by the same code).
    Each run is copied to a temporary name and renamed, so an interrupted copy leaves
    nothing that looks finished."""
    source, out = _stages_source(source, out), Path(out).resolve()
    source_steps = plan_entry(source, "transfer_steps") or {}
    out_steps = plan_entry(out, "transfer_steps") or {}
    out_methods = set(plan_entry(out, "methods") or ())
    current = pinned_fingerprint()
    copied = other_code = 0
    for pair in pairs:
        same_steps = pair in out_steps and source_steps.get(pair) == out_steps[pair]
        for stage in (*COPYABLE_STAGES, "transfer") if same_steps else COPYABLE_STAGES:
            stage_dir = source / "runs" / pair / stage
            for result in sorted(stage_dir.glob("*/seed*/result.json")):
                run = result.parent
                if stage == "transfer" and transfer_run_method(run.parent.name) not in out_methods:
                    continue  # a method the plan leaves out
                target = out / "runs" / run.relative_to(source / "runs")
                if target.exists():
                    continue
                if stage == "transfer" and fingerprint_of_run(run) != current:
                    other_code += 1
                    continue
                partial = target.with_name(f".{target.name}.copying")
                shutil.rmtree(partial, ignore_errors=True)
                # checkpoints are not needed by a finished run
                shutil.copytree(run, partial, ignore=shutil.ignore_patterns("checkpoints"))
                repoint_result(partial, target)  # its model.pt, not the other protocol's
                partial.rename(target)
                copied += 1
    return StageCopy(copied, other_code, current)


def run_protocol(
    pairs: Sequence[str],
    *,
    budget: str = "smoke",
    methods: Sequence[str] = ("pved", NO_TRANSFER),
    out: Path | str,
    address: str | None = None,
    workers: int | None = None,
    retries: int = 2,
    live: bool = True,
    backend: str = "auto",
    stages_from: Path | str | Sequence[Path | str] | None = None,
    selection_from: Path | str | None = None,
    preregistration: Sequence[Path | str] = (),
    exploratory: bool = False,
    checkpoint_seconds: float | None = CHECKPOINT_SECONDS,
) -> dict[str, Any]:
    """Run (or resume) the protocol into ``out``; returns ``summary.json``'s content.

    A method beyond the paper at the paper's budget starts only with a valid
    ``preregistration`` (files, one a method; their selections are the plan's) or with
    ``exploratory`` (its results are then marked so), checked before any work
    (:func:`pved.protocol.preregistration.check_gate`).

    A directory that already holds a protocol must hold the same one (pairs, methods,
    budget): its finished runs are reused and unfinished ones resumed. ``backend``: see
    :func:`pved.protocol.runner.run_jobs`. ``stages_from``: protocol directories (one,
    or several in order) whose finished policies, pairs, models and banks are copied in
    first (:func:`copy_stage_runs`), e.g. the ``quick`` protocol of a pair before its
    ``paper`` one; a run already copied from an earlier one is kept. ``selection_from``:
    a protocol directory whose β and model selections are used instead of tuning here
    (:func:`fixed_selections`). ``checkpoint_seconds``: each RL run also checkpoints after
    the update that ends that much wall time after its last checkpoint, so that a kill or
    a lost node costs a run at most about that much (``pved transfer``'s default; no run's
    config holds it, so changing it redoes nothing)."""
    sources: list[Path | str] = (
        []
        if stages_from is None
        else [stages_from]
        if isinstance(stages_from, str | Path)
        else list(stages_from)
    )
    # names checked before the selection
    ProtocolPlan(pairs, methods, budget, Path(out), checkpoint_seconds=checkpoint_seconds)
    fixed = (
        None if selection_from is None else fixed_selections(selection_from, pairs, methods, budget)
    )
    gate = check_gate(pairs, methods, budget, out, fixed, preregistration, exploratory, sources)
    fixed = gate.fixed or None  # a pre-registration's selection is the plan's
    plan = ProtocolPlan(
        pairs, methods, budget, Path(out), fixed, checkpoint_seconds=checkpoint_seconds
    )
    resolve_backend(backend, address)  # before anything is written
    if workers is not None:
        check_int("--workers", workers, low=1)
    check_int("--retries", retries, low=0)
    check_writable("--out", plan.out)
    for source in sources:
        _stages_source(source, plan.out)
    if address:
        check_reachable(address)
    plan_path = plan.out / PLAN_FILE
    description = plan.describe()
    if plan_path.exists():
        try:
            written = json.loads(plan_path.read_text())
        except json.JSONDecodeError:
            raise PvedError(f"{plan_path} is corrupt; remove it or use another --out") from None
        # a plan written before paths in records were relative: the same plan
        existing = relative_plan(written) if isinstance(written, dict) else written
        current = json.loads(json.dumps(description))
        if {k: existing.get(k) for k in description} != current:
            if not _widens(existing, current):
                raise PvedError(
                    f"{plan.out} holds a protocol with other settings "
                    f"(pairs {existing.get('pairs')}, methods {existing.get('methods')}, "
                    f"budget {existing.get('budget', {}).get('name')}); use another --out"
                )
            # A plan from before a wider beta search: it only gains tuning runs, and every
            # finished run keeps its meaning, so it is carried on; the earlier plan is kept.
            earlier = [*existing.pop("earlier_plans", []), existing]
            atomic_write_json(
                plan_path,
                {**description, "pved_version": __version__, "earlier_plans": earlier},
            )
            print(
                f"{plan_path}: the beta search is wider than this protocol's plan had it; "
                "its finished runs are kept",
                file=sys.stderr,
            )
        elif existing != written:  # the same plan, its paths now written relative
            atomic_write_json(plan_path, existing)
    else:
        plan.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(plan_path, {**description, "pved_version": __version__})
    for source in sources:
        print(copy_stage_runs(source, plan.out, plan.pairs).describe(source), file=sys.stderr)
    write_record(plan.out, gate)  # before an evaluation run can start
    report = run_jobs(
        plan,
        workers=workers,
        address=address,
        retries=retries,
        status_path=plan.out / "status.json",
        log_dir=plan.out / "failures",
        live=live,
        backend=backend,
    )
    return summarize(plan.out, report)


def _widens(existing: Mapping[str, Any], current: Mapping[str, Any]) -> bool:
    """Whether plan ``current`` is plan ``existing`` with a wider beta search: the same
    pairs, methods and transfer steps, every budget field ``existing`` records the same
    (a field it predates may be new), and each of its beta grids a part of the current
    one."""
    if any(existing.get(k) != current[k] for k in ("pairs", "methods", "transfer_steps")):
        return False
    old_budget = existing.get("budget")
    if not isinstance(old_budget, dict) or any(
        current["budget"].get(k, object()) != v for k, v in old_budget.items()
    ):
        return False
    old_grids = existing.get("beta_grids")
    if not isinstance(old_grids, dict) or set(old_grids) != set(current["beta_grids"]):
        return False
    for pair, grids in current["beta_grids"].items():
        old = old_grids[pair]
        if not isinstance(old, dict) or set(old) != set(grids):
            return False
        if any(not set(old[m]) <= set(grid) for m, grid in grids.items()):
            return False
    return True


def pair_panel(
    plan: ProtocolPlan, pair: str, results: Mapping[str, Any], title: str | None = None
) -> Panel | None:
    """The learning curves of every method's finished evaluation runs on ``pair`` (one
    panel of Fig. 3), or None when no method has any."""
    from pved.analysis.curves import Panel, load_curve

    metric = plan.resolved[pair].preset.metric
    curves = []
    for method in plan.methods:
        run_dirs = [
            j.run_dir
            for j in plan.evaluation_jobs(pair, method)
            if j.key in results and j.run_dir is not None
        ]
        if run_dirs:
            curves.append(
                load_curve(method, run_dirs, list(range(len(run_dirs))), f"eval/{metric}")
            )
    if not curves:
        return None
    return Panel(
        title=title or pair,
        ylabel=metric.replace("_", " "),
        curves=curves,
        bounds=(0.0, 1.0) if metric == "success_rate" else None,
    )


def summarize(out: Path | str, report: RunnerReport | None = None) -> dict[str, Any]:
    """Write ``selection.json``, ``summary.json``, ``summary.md``, ``curves.png`` and
    ``curves-<pair>.png`` of a protocol directory from its run files; returns the summary.

    ``report`` (from the run that just ended) adds failed and blocked jobs; without it
    (``pved plot``) the summary lists the runs that are missing instead."""
    return _summarize(out, report)[0]


def _summarize(
    out: Path | str, report: RunnerReport | None = None
) -> tuple[dict[str, Any], list[Panel]]:
    """:func:`summarize`, also returning the per-pair panels it drew (for ``pved plot``'s
    combined figure, so the runs are read and bootstrapped once)."""
    from pved.analysis.curves import (
        bootstrap_summary,
        plot_panels,
        reward_scale,
        steps_to_baseline_finals,
    )

    out = Path(out).resolve()
    plan = ProtocolPlan.load(out)
    results = finished_results(plan)
    summary: dict[str, Any] = {
        "pved_version": __version__,
        "budget": plan.budget.name,
        "pairs": {},
        "selection": plan.selection,
        "failed": dict(report.failed) if report else {},
        "blocked": list(report.blocked) if report else [],
        "reused": len(report.reused) if report else None,
        "wall_s": report.wall_s if report else None,
    }
    panels = []
    every_run: list[str] = []
    for pair in plan.pairs:
        preset = plan.resolved[pair].preset
        metric = preset.metric
        methods: dict[str, Any] = {}
        for method in plan.methods:
            jobs = plan.evaluation_jobs(pair, method)
            done = [j for j in jobs if j.key in results]
            entry: dict[str, Any] = {
                "runs_planned": len(jobs),
                "runs_finished": len(done),
                "missing": [j.key for j in jobs if j.key not in results],
            }
            state = plan.selection.get(pair, {}).get(method, {})
            if "beta" in state:
                entry.update(beta=state["beta"], init=state.get("init"))
            if state.get("init") is not None:
                model_dir = run_path(plan.runs, pair, "model", plan._model(method), state["init"])
                if (model_dir / "result.json").exists():
                    model_result = json.loads((model_dir / "result.json").read_text())
                    val = {
                        k.removeprefix("val/"): v
                        for k, v in model_result.items()
                        if k.startswith("val/")
                    }
                    if "shared_collapsed" in model_result:
                        entry["shared_collapsed"] = model_result["shared_collapsed"]
                    elif "kl_SS" in val:  # trained before result.json recorded it
                        entry["shared_collapsed"] = shared_subspace_collapsed(val)
            if done:
                scores = np.array([results[j.key][f"final/{metric}"] for j in done], float)
                # the mean's interval two-level, over the source policies (a reference
                # method has none: its source tag only numbers its extra seeds) and seeds
                entry["final"] = bootstrap_summary(
                    scores,
                    seeds=[j.kwargs["seed"] for j in done],
                    sources=None
                    if method in REFERENCE_METHODS
                    else [j.tags["source_policy"] for j in done],
                )
                entry["runs"] = [
                    {
                        "key": j.key,
                        "seed": j.kwargs["seed"],
                        "source_policy": j.tags["source_policy"],
                        metric: float(results[j.key][f"final/{metric}"]),
                        "result": record_path(j.run_dir / "result.json", out)
                        if j.run_dir
                        else None,
                    }
                    for j in done
                ]
                # the code each run was made by (pved.provenance): a group made under two
                # fingerprints, or none, may differ by the code's arithmetic
                entry["fingerprints"] = count_fingerprints(
                    [fingerprint_of_run(j.run_dir) if j.run_dir else UNKNOWN for j in done]
                )
                # the shaping term against the env's reward: why a β does what it does
                scale = reward_scale([j.run_dir for j in done if j.run_dir is not None])
                if scale is not None:
                    entry["reward_scale"] = scale
            methods[method] = entry
        panel = pair_panel(plan, pair, results)
        curves = panel.curves if panel else []
        for curve in curves:
            methods[curve.method]["curve_steps"] = curve.steps.tolist()
            methods[curve.method]["curve_mean"] = curve.mean.tolist()
        # steps to plain PPO's final performance (its mean curve's last point), the
        # paper's speed measure, and to the oracle's, where PPO learns nothing to reach
        for method, reach in steps_to_baseline_finals(curves, (NO_TRANSFER, ORACLE)).items():
            methods[method].update(reach)
        mark_summary(out, methods)  # pre-registered or exploratory (preregistration.py)
        summary["pairs"][pair] = {"metric": metric, "methods": methods}
        banked = _source_success(plan, pair) if metric == "success_rate" else {}
        if banked:  # only then, so summaries without banks read as before
            summary["pairs"][pair]["source_success"] = banked
        every_run.extend(fp for m in methods.values() for fp in _each_run(m))
        if panel is not None:
            panels.append(panel)
            plot_panels([panel], out / f"curves-{pair}.png")
    if panels:
        plot_panels(panels, out / "curves.png")
    # the numeric fingerprints the finished transfer runs were made under, with counts
    summary["fingerprints"] = count_fingerprints(every_run)
    atomic_write_json(out / "selection.json", plan.selection)
    atomic_write_json(out / "summary.json", summary)
    atomic_write_bytes(out / "summary.md", _markdown(summary, plan).encode())
    return summary, panels


def _source_success(plan: ProtocolPlan, pair: str) -> dict[str, float]:
    """Each source policy's success on the target task, as its bank's rollouts measured it
    (``build_bank``'s result), by source index; the banks not made yet are left out. A
    source that fails its own task has nothing to transfer (issue 64: reacher's source 2)."""
    out: dict[str, float] = {}
    for k in range(plan.budget.source_policies):
        result = plan._bank_path(pair, k).parent / "result.json"
        if result.is_file():
            rate = json.loads(result.read_text()).get("success_rate")
            if isinstance(rate, int | float):
                out[str(k)] = float(rate)
    return out


def _fmt(x: float | None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return f"{x:.{digits}f}"


def _with_ci(value: float, ci: Sequence[float]) -> str:
    return f"{_fmt(value)} [{_fmt(ci[0])}, {_fmt(ci[1])}]"


def _scale_cells(method_summary: Mapping[str, Any], method: str) -> tuple[str, str]:
    """The summary table's two reward-scale cells of one method (``–`` without a shaping
    term; ``none`` for a guide form, align or prior, which pays none): the Eq. 10 term with its
    distance D (a KL in nats, or a point-code model's squared distance; only for the
    ``eq10`` form not annealed, where D = term / −β) and the env's reward, each at the
    first and last rollout."""
    scale = method_summary.get("reward_scale")
    if not scale:
        return "–", "–"
    first, last = scale["shaping_first"], scale["shaping_last"]
    shaping = f"{first:.3g} → {last:.3g}"
    recipe = get_method(method)
    if recipe.shaping_form in GUIDE_FORMS:  # its term is in the loss, not the reward
        shaping = "none (a loss on the mean action)"
    beta = method_summary.get("beta")
    # D = term / −β only where the weight is β all along (not an annealed term)
    plain_eq10 = recipe.shaping_form == "eq10" and recipe.anneal is None
    if isinstance(beta, int | float) and beta > 0 and plain_eq10:
        shaping += f" (D {-first / beta:,.4g} → {-last / beta:,.4g})"
    env = f"{scale['env_reward_first']:.3g} → {scale['env_reward_last']:.3g}"
    return shaping, env


def _each_run(method_summary: Mapping[str, Any]) -> list[str]:
    """The fingerprint of each of a method's finished runs, from its counts."""
    counts = method_summary.get("fingerprints", {})
    return [fp for fp, n in counts.items() for _ in range(n)]


def _markdown(summary: Mapping[str, Any], plan: ProtocolPlan) -> str:
    from pved.analysis.curves import REPS, SEED, reach_cell

    b = plan.budget
    lines = [
        f"# Protocol summary ({b.name} budget)",
        "",
        f"Tuning seeds {list(b.tuning_seeds)}; evaluation seeds {list(b.evaluation_seeds)} "
        f"x {b.source_policies} source policies; {b.model_inits} model initialisations. "
        "Final performance over the evaluation runs: the mean with its 95% interval from the "
        f"two-level bootstrap over source policies and seeds ({REPS:,} resamples, seed "
        f"{SEED}), and the interquartile mean (IQM) with a one-level 95% interval over runs "
        "(rliable).",
        "",
    ]
    fingerprints = summary.get("fingerprints") or {}
    if fingerprints:
        made = ", ".join(f"{fp} ({n} runs)" for fp, n in fingerprints.items())
        lines += [f"Numeric fingerprints the runs were made under: {made}.", ""]
    for pair, info in summary["pairs"].items():
        metric = info["metric"]
        lines += [
            f"## {pair} ({metric})",
            "",
            f"![curves](curves-{pair}.png)",
            "",
            "| method | runs | mean [95% CI] | IQM [95% CI, one-level] | steps to PPO's final "
            "| steps to the oracle's final | beta | init | shaping term per step, first → "
            "last rollout (Eq. 10's form: D = term / −β) | env reward per step, first → last "
            "rollout |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for method, m in info["methods"].items():
            final = m.get("final")
            if final:
                mean = _with_ci(final["mean"], final["mean_ci"])
                iqm = _with_ci(final["iqm"], final["iqm_ci"])
            else:
                mean = iqm = "–"
            reach = [reach_cell(m, baseline) for baseline in (NO_TRANSFER, ORACLE)]
            beta = m.get("beta", "–")
            init = m.get("init", "–")
            if m.get("shared_collapsed"):  # its shaping reward is zero: plain PPO in effect
                init = f"{init} (collapsed)"
            shaping, env_reward = _scale_cells(m, method)
            lines.append(
                f"| {method}{' (exploratory)' if m.get('exploratory') else ''} | "
                f"{m['runs_finished']}/{m['runs_planned']} | {mean} | {iqm} | "
                f"{reach[0]} | {reach[1]} | {beta} | {init} | {shaping} | {env_reward} |"
            )
        lines.append("")
        banked = info.get("source_success")
        if banked:
            rates = ", ".join(
                f"{k}: {_fmt(v, 2)}{' (fails its own task)' if v < SOURCE_BAR else ''}"
                for k, v in banked.items()
            )
            lines += [f"Source policies' success on the target task (their banks): {rates}.", ""]
        for method, state in summary["selection"].get(pair, {}).items():
            scored = (
                f"area under the learning curve of {metric}"
                if state.get("select_by") == "auc"
                else metric
            )
            lines.append(f"Selection of {method} (mean {scored} over the tuning seeds):")
            lines.append("")
            where = state.get("selected_in")
            if where:
                lines.append(
                    f"- made in {where['protocol']} ({where['budget']} budget, tuning seeds "
                    f"{where['tuning_seeds']}; `--selection-from`): beta {state['beta']:g}, "
                    f"init {state['init']}"
                )
            for cand in state.get("candidates", []):
                lines.append(
                    f"- beta {cand['beta']:g}, init {cand['init']}: "
                    f"{_fmt(float(np.mean(cand['scores'])))} (runs: "
                    f"{', '.join(_fmt(s) for s in cand['scores'])}; mean final return "
                    f"{_fmt(float(np.mean(cand['returns'])), 2)})"
                )
            lines.append("")
    if summary["failed"] or summary["blocked"]:
        lines += ["## Failed runs", ""]
        for key, err in summary["failed"].items():
            lines.append(f"- `{key}`: {err} (tracebacks in failures/)")
        for key in summary["blocked"]:
            lines.append(f"- `{key}`: not run, a run it needs failed")
        lines.append("")
    return "\n".join(lines)


def plot_protocols(dirs: Sequence[Path | str], combined: Path | str | None = None) -> list[Path]:
    """Redraw each protocol directory's summary and curves from its finished runs
    (``pved plot``); with ``combined``, also one figure with every pair of every
    directory (Fig. 3's layout). Returns the figures written."""
    from pved.analysis.curves import plot_panels

    if combined is not None:
        check_writable("--out", combined, directory=False)
    for d in dirs:  # each DIR gets its summary and curves again
        check_writable("DIR", d)
    written: list[Path] = []
    panels: list[Panel] = []
    for d in dirs:
        out = Path(d).resolve()
        budget = ProtocolPlan.load(out).budget.name
        _, pair_panels = _summarize(out)
        written.append(out / "curves.png")
        # the combined figure may hold one pair at several budgets: say which in the title
        panels += [dataclasses.replace(p, title=f"{p.title} ({budget})") for p in pair_panels]
    if combined is not None and panels:
        written.append(plot_panels(panels, Path(combined)))
    return [p for p in written if p.exists()]
