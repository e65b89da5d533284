"""Pre-registration of a method beyond the paper before its paper-budget evaluation
(docs/decisions/protocol.md, "Pre-registration").

A method the paper does not define (``pved-align``, ...) is designed here, after looking
at runs; its paper-budget evaluation is evidence only if what it evaluates was fixed
before: the method and every hyper-parameter (β and the model initialisation per pair,
the recipe's form and anneal, the settings its code gives the runs) chosen on tuning
seeds only and written to a file committed to git before the first evaluation run
starts. ``pved protocol --budget paper --methods X ... --preregistration FILE`` checks
that (:func:`check_gate`, before any work): the file is tracked by git, unmodified in
the working tree, last changed in a commit that is an ancestor of HEAD (``git log HEAD
-- FILE``) and, where the protocol's evaluation runs of X have started, committed
before the first of them started; its method, budget, seed counts, recipe and run
settings are the protocol's; and the selection used is the file's (the file's β and
init are the selection, or equal to ``--selection-from``'s).
Without a valid file the protocol refuses to start, unless ``--exploratory`` is given:
then X's results are marked ``exploratory`` in ``summary.json``, and ``pved claims`` and
``pved scoreboard`` print that label. Paper methods and the references are not gated;
nor is any budget but the paper's (``paper``, ``paper-45``, ``paper-wide``).

The file (TOML)::

    method = "pved-align"
    budget = "paper"                  # the budget whose evaluation it registers
    date = 2026-12-06                 # when the choices were made
    evaluation_seeds = 5              # per source policy (the budget's count)
    source_policies = 3
    tuning_seeds = [2000, 4000, 6000] # where β and init were chosen (no evaluation seed)
    tuning_budget = "quick"           # the budget of those tuning runs
    code_commit = "3a4db49..."        # the commit `pved choose --write` ran from
    [settings]                        # the recipe (pved.transfer.methods.Method fields)
    model = "pved"
    shaping_form = "align"
    [pairs.reacher]
    beta = 0.1
    init = 0
    screen_fingerprints = { ff960b14702b = 15 }  # provenance: the code of its screen runs
    [pairs.reacher.run_config]        # what its evaluation runs' configs get, pinned
    align_anneal = 0.3
    guide_limits = { grad_ratio = 1.0, ... }
    ppo = { lr = 0.0003, ... }
    model_config = { epochs = 100, ... }
    ...

``run_config`` pins the settings of the method's code, not only its recipe: the config
this code's :func:`pved.experiments.transfer_spec.transfer_spec` gives each evaluation
run, less the run's name and inputs (β, its seed, the model's and the bank's digests;
:func:`run_settings`): the guide's anneal and limits, PPO's settings, the episode
counts; and the config of the model it shapes with, which the protocol trains after the
registration, less its seed (:func:`model_settings`). The gate compares them with what
each evaluation run would get and refuses, naming the key, where they differ: a guide
changed after its registration is not the method registered. Nor is one whose code
changed with its settings the same: the gate refuses where any file under
``src/pved/{transfer,rl,models}/`` (:data:`GUIDE_CODE`) in the running code's working
tree differs from ``code_commit``, or git cannot tell (:func:`changed_code`).

A run's start: the earliest of the time this protocol first let X's evaluation runs
start (``OUT/preregistration.json``, written before they can) and the ``config.json``
times of X's evaluation run directories already there (in ``OUT`` or a ``--stages-from``
directory); a protocol older than this check has only the latter, an upper bound.
"""

from __future__ import annotations

import datetime
import inspect
import json
import math
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pved.config import get_budget
from pved.errors import PvedError
from pved.experiments.transfer_spec import transfer_spec
from pved.protocol.plan import ProtocolPlan
from pved.record_paths import record_path
from pved.runs import atomic_write_json, to_jsonable
from pved.spec import toml_value
from pved.transfer.methods import NO_TRANSFER, REFERENCE_METHODS, get_method

RECORD = "preregistration.json"
"""A protocol directory's record of its gated methods' status (pre-registered or
exploratory) and of when their evaluation runs were first let start."""
EXPLORATORY = "exploratory"
PREREGISTERED = "pre-registered"
PAPER_STEPS = "paper"
"""The budgets gated: those whose runs are the paper's length (``paper``, ``paper-45``,
``paper-wide``)."""
_FIELDS: dict[str, type | tuple[type, ...]] = {
    "method": str,
    "budget": str,
    "date": (datetime.date, datetime.datetime),
    "evaluation_seeds": int,
    "source_policies": int,
    "tuning_seeds": list,
    "pairs": dict,
    "code_commit": str,
}


def gated_methods(methods: Sequence[str], budget: str) -> list[str]:
    """The methods of ``methods`` whose evaluation at ``budget`` needs a pre-registration:
    beyond the paper, not a reference, at a budget of the paper's length."""
    if get_budget(budget).steps_budget != PAPER_STEPS:
        return []
    return [m for m in methods if not get_method(m).paper and m not in REFERENCE_METHODS]


def _git(path: Path, *args: str) -> str:
    """``git ARGS`` in ``path``'s directory: its stdout, or PvedError (one line)."""
    try:
        done = subprocess.run(
            ["git", "-C", str(path.parent), *args], capture_output=True, text=True, check=False
        )
    except OSError as exc:
        raise PvedError(f"{path}: git cannot be run ({exc})") from None
    if done.returncode != 0:
        why = " ".join(done.stderr.split()) or f"git {args[0]} failed"
        raise PvedError(f"{path}: {why}")
    return done.stdout.strip()


def committed(path: Path) -> tuple[str, float]:
    """(commit, commit time) of the commit that last changed ``path``, found from HEAD (so
    an ancestor of HEAD); PvedError where the file is not tracked, differs from HEAD's
    (in the working tree or the index), or was never committed."""
    if not path.is_file():
        raise PvedError(f"--preregistration {path}: no such file")
    try:
        _git(path, "ls-files", "--error-unmatch", "--", path.name)
    except PvedError:
        raise PvedError(f"--preregistration {path}: not tracked by git (commit it)") from None
    if _git(path, "status", "--porcelain", "--untracked-files=no", "--", path.name):
        raise PvedError(f"--preregistration {path}: changed since its last commit (commit it)")
    line = _git(path, "log", "-1", "--format=%H %ct", "HEAD", "--", path.name)
    if not line:
        raise PvedError(f"--preregistration {path}: in no commit of HEAD's history")
    commit, when = line.split()
    return commit, float(when)


def code_commit() -> str:
    """HEAD of the checkout the running code lies in (:data:`PACKAGE`), which ``pved
    choose --write`` records; PvedError (one line) outside a git checkout or without git."""
    return _git(PACKAGE / "__init__.py", "rev-parse", "HEAD")


def changed_code(commit: str) -> list[str]:
    """The files under :data:`GUIDE_CODE` in which the running code's working tree
    (:data:`PACKAGE`'s checkout: tracked files changed, staged or not, and files not
    ignored that git does not track) differs from ``commit``; PvedError (one line) where
    git cannot say, e.g. no git, no checkout, or a commit it does not hold."""
    where = PACKAGE / "__init__.py"
    changed = _git(where, "diff", "--name-only", commit, "--", *GUIDE_CODE).splitlines()
    new = _git(
        where, "ls-files", "--others", "--exclude-standard", "--full-name", "--", *GUIDE_CODE
    )
    return sorted({*changed, *new.splitlines()} - {""})


def _check_code(path: Path, data: Mapping[str, Any]) -> None:
    """The guide's code is the registration's: no file under :data:`GUIDE_CODE` differs
    from the file's ``code_commit`` (a change that leaves every setting the same still
    changes the method); PvedError naming the first file that does."""
    commit = data[CODE_COMMIT]
    try:
        changed = changed_code(commit)
    except PvedError as exc:
        raise PvedError(
            f"--preregistration {path}: cannot compare the code with {CODE_COMMIT} "
            f"{commit[:12]} ({exc})"
        ) from None
    if changed:
        more = f" and {len(changed) - 1} more" if len(changed) > 1 else ""
        raise PvedError(
            f"--preregistration {path}: {changed[0]}{more} differs from {CODE_COMMIT} "
            f"{commit[:12]}, where the method was registered"
        )


def read_file(path: Path) -> dict[str, Any]:
    """The pre-registration at ``path``, its fields checked for presence and type."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        why = " ".join(str(exc).split())
        raise PvedError(f"--preregistration {path}: unreadable ({why})") from None
    for name, kind in _FIELDS.items():
        if not isinstance(data.get(name), kind) or isinstance(data.get(name), bool):
            raise PvedError(f"--preregistration {path}: no {name!r} of the right type")
    for pair, choice in data["pairs"].items():
        beta, init = (choice.get(k) if isinstance(choice, dict) else None for k in ("beta", "init"))
        if not isinstance(beta, int | float) or isinstance(beta, bool) or not math.isfinite(beta):
            raise PvedError(f"--preregistration {path}: pairs.{pair} has no number 'beta'")
        if not isinstance(init, int) or isinstance(init, bool) or init < 0:
            raise PvedError(f"--preregistration {path}: pairs.{pair} has no 'init' >= 0")
    if not all(isinstance(s, int) for s in data["tuning_seeds"]):
        raise PvedError(f"--preregistration {path}: 'tuning_seeds' are not all integers")
    return data


def _check_design(path: Path, data: Mapping[str, Any], pairs: Sequence[str], budget: str) -> None:
    """The file registers this protocol's design: its budget, seed counts and pairs, the
    method's recipe, and tuning seeds that the budget never evaluates on."""
    b = get_budget(budget)
    wanted = {
        "budget": budget,
        "evaluation_seeds": len(b.evaluation_seeds),
        "source_policies": b.source_policies,
    }
    for name, value in wanted.items():
        if data[name] != value:
            raise PvedError(
                f"--preregistration {path}: {name} {data[name]!r}, the protocol's is {value!r}"
            )
    overlap = sorted(set(data["tuning_seeds"]) & set(b.evaluation_seeds))
    if overlap:
        raise PvedError(f"--preregistration {path}: tuned on evaluation seeds {overlap}")
    missing = [p for p in pairs if p not in data["pairs"]]
    if missing:
        raise PvedError(f"--preregistration {path}: no choice for {', '.join(missing)}")
    recipe = get_method(data["method"])
    for name, value in (data.get("settings") or {}).items():
        if not hasattr(recipe, name):
            raise PvedError(f"--preregistration {path}: settings.{name} is no field of a method")
        have = getattr(recipe, name)
        if (list(have) if isinstance(have, tuple) else have) != value:
            raise PvedError(
                f"--preregistration {path}: settings.{name} = {value!r}, but "
                f"{data['method']}'s is {have!r}"
            )


RUN_CONFIG = "run_config"
"""A pair's table of the settings its evaluation runs' configs get (:func:`method_settings`)."""
INPUTS = ("beta", "model", "bank")
"""A guided run's config entries that are its inputs, registered apart (β per pair) or
made by the protocol (the model's and the bank's digests)."""
_SPEC_ARGS = frozenset(inspect.signature(transfer_spec).parameters)


IDENTITY = ("stage", "pair", "method")
"""A transfer run's config entries that name the run, which the file says elsewhere."""
SEED = "seed"
"""The entry of a run's ``ppo`` config and of its model's config that differs run by run
(the evaluation seed, the model initialisation: registered as ``init``)."""
GUIDE_CODE = ("transfer", "rl", "models")
"""The folders of the package (``src/pved/``) whose code makes a guided run: a change to
any file in them after the registration's commit is a method not registered."""
CODE_COMMIT = "code_commit"
"""The file's entry of the commit of the code ``pved choose --write`` ran from."""
PACKAGE = Path(__file__).resolve().parents[1]
"""The package whose checkout's working tree is compared with ``code_commit``."""


def run_settings(config: Mapping[str, Any]) -> dict[str, Any]:
    """What a transfer run's ``config`` fixes of its behaviour beyond its inputs: every
    entry but :data:`IDENTITY` and :data:`INPUTS`, its ``ppo`` less the seed. PPO's
    learner, the budget's steps and the episode counts are the baseline's too, but a
    change to them after the registration changes the registered method's runs."""
    settings = {k: v for k, v in config.items() if k not in INPUTS and k not in IDENTITY}
    if isinstance(settings.get("ppo"), Mapping):
        settings["ppo"] = {k: v for k, v in settings["ppo"].items() if k != SEED}
    return settings


def method_settings(config: Mapping[str, Any], baseline: Mapping[str, Any]) -> dict[str, Any]:
    """The entries of a transfer run's ``config`` that its method adds to ``baseline``,
    the config of plain PPO's run of the pair (the learner, the budget and the pair's
    identity, which the two share), less its :data:`INPUTS`: what the method's code
    decides beyond β and the model, its recipe's fields among them."""
    return {k: v for k, v in config.items() if k not in baseline and k not in INPUTS}


def _as_written(value: Any) -> Any:
    """``value`` as a TOML file holds it once written (:func:`pved.spec.toml_value`)."""
    return tomllib.loads(f"v = {toml_value(json.loads(json.dumps(to_jsonable(value))))}")["v"]


def evaluation_configs(
    plan: ProtocolPlan, pair: str, method: str
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(plain PPO's config, the config of each evaluation run of ``method`` on ``pair``)
    as this code's :func:`transfer_spec` resolves them for ``plan``, JSON as
    ``config.json`` holds it. The model and bank are only hashed there, and a protocol
    makes them after the gate, so an empty stand-in takes their place (their digests are
    :data:`INPUTS`, never compared)."""
    plan.expand({})  # the selections made elsewhere (fixed) give the evaluation runs
    jobs = plan.evaluation_jobs(pair, method)
    if not jobs:
        raise PvedError(f"{method} on {pair}: no selection, so no evaluation runs to pin")
    with tempfile.TemporaryDirectory() as tmp:
        stand_in = Path(tmp) / "stand-in"
        stand_in.write_bytes(b"")

        def config(kwargs: Mapping[str, Any]) -> dict[str, Any]:
            args = {k: v for k, v in kwargs.items() if k in _SPEC_ARGS}
            args.update({k: stand_in for k in ("model_path", "bank_path") if k in args})
            resolved = transfer_spec(**args).config
            return dict(json.loads(json.dumps(to_jsonable(resolved))))

        baseline = config({**jobs[0].kwargs, "method": NO_TRANSFER})
        return baseline, [config(job.kwargs) for job in jobs]


def model_settings(plan: ProtocolPlan, pair: str, method: str) -> list[dict[str, Any]]:
    """The config of the model each evaluation run of ``method`` on ``pair`` in ``plan``
    shapes with, less its seed (the registered init), JSON as ``config.json`` holds it:
    the model job ``plan`` makes for the run's model file, its config resolved as the
    model stage resolves it (``preset.model_config(model, seed=, epochs=)``, Table 1's
    α weights, lr, epochs...). The model is trained inside the protocol, after the
    registration, so what trains it is the method's as much as its guide is."""
    made = {job.run_dir / "model.pt": job for job in plan.expand({}) if job.run_dir is not None}
    preset = plan.resolved[pair].preset
    configs: list[dict[str, Any]] = []
    for job in plan.evaluation_jobs(pair, method):
        model_job = made.get(Path(job.kwargs["model_path"]))
        if model_job is None:
            raise PvedError(f"{method} on {pair}: no model job makes {job.kwargs['model_path']}")
        args = model_job.kwargs
        resolved = preset.model_config(args["model"], seed=args["seed"], epochs=args["epochs"])
        config = dict(json.loads(json.dumps(to_jsonable(resolved))))
        configs.append({k: v for k, v in config.items() if k != SEED})
    return configs


def evaluation_settings(plan: ProtocolPlan, pair: str, method: str) -> list[dict[str, Any]]:
    """The ``run_config`` each evaluation run of ``method`` on ``pair`` in ``plan`` gets:
    :func:`run_settings` of its config (:func:`evaluation_configs`) with its model's
    config (:func:`model_settings`) as ``model_config``, as a TOML file holds it."""
    _, configs = evaluation_configs(plan, pair, method)
    models = model_settings(plan, pair, method)
    return [
        _as_written({**run_settings(config), "model_config": model})
        for config, model in zip(configs, models, strict=True)
    ]


def differing_keys(a: Mapping[str, Any], b: Mapping[str, Any], prefix: str = "") -> list[str]:
    """The dotted keys (sorted, nested tables entered) whose values differ between ``a``
    and ``b``, a key that only one has among them."""
    keys: list[str] = []
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        if isinstance(x, Mapping) and isinstance(y, Mapping):
            keys += differing_keys(x, y, f"{prefix}{key}.")
        elif key not in a or key not in b or x != y:
            keys.append(f"{prefix}{key}")
    return keys


def _at(table: Mapping[str, Any], dotted: str) -> str:
    value: Any = table
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            return "none"
        value = value[part]
    return repr(value)


def _check_run_config(path: Path, data: Mapping[str, Any], plan: ProtocolPlan, method: str) -> None:
    """Each pair's ``run_config`` is what every evaluation run of ``method`` in ``plan``
    would get (:func:`evaluation_settings`); PvedError naming the first key that differs."""
    for pair in plan.pairs:
        pinned = data["pairs"][pair].get(RUN_CONFIG)
        if not isinstance(pinned, dict):
            raise PvedError(
                f"--preregistration {path}: pairs.{pair} has no {RUN_CONFIG!r} table (the "
                "settings its evaluation runs get; `pved choose --write` writes it)"
            )
        for wanted in evaluation_settings(plan, pair, method):
            differ = differing_keys(pinned, wanted)
            if differ:
                key = differ[0]
                raise PvedError(
                    f"--preregistration {path}: pairs.{pair}.{RUN_CONFIG}.{key} is "
                    f"{_at(pinned, key)}, but this code gives {method}'s evaluation runs "
                    f"{_at(wanted, key)}"
                )


def _selection(
    path: Path, data: Mapping[str, Any], pairs: Sequence[str], fixed: dict[str, Any]
) -> None:
    """The file's β and init of each pair: equal to ``fixed``'s (``--selection-from``)
    where it has one, else put into ``fixed`` as the selection, in place."""
    method = data["method"]
    for pair in pairs:
        mine = data["pairs"][pair]
        used = fixed.get(pair, {}).get(method)
        if used is None:
            fixed.setdefault(pair, {})[method] = {
                "beta": float(mine["beta"]),
                "init": int(mine["init"]),
                "protocol": record_path(path),
                "budget": str(data.get("tuning_budget", "?")),
                "tuning_seeds": list(data["tuning_seeds"]),
                "candidates": [],
            }
            continue
        if not math.isclose(float(used["beta"]), float(mine["beta"]), rel_tol=1e-9) or int(
            used["init"]
        ) != int(mine["init"]):
            raise PvedError(
                f"--preregistration {path}: {method} on {pair} registered beta "
                f"{mine['beta']:g} init {mine['init']}, the selection used is beta "
                f"{float(used['beta']):g} init {used['init']}"
            )


def _record(out: Path) -> dict[str, Any]:
    """``OUT/preregistration.json`` (empty where there is none or it is unreadable)."""
    try:
        data = json.loads((Path(out) / RECORD).read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def evaluation_started(
    plan: ProtocolPlan, method: str, others: Sequence[Path | str] = ()
) -> float | None:
    """When ``method``'s first evaluation run of ``plan`` started, as far as the files
    say (module docstring); None where none has."""
    plan.expand({})  # the selections made elsewhere (fixed) give the evaluation runs
    times: list[float] = []
    allowed = _record(plan.out).get("evaluation_allowed_at", {}).get(method)
    if isinstance(allowed, int | float):
        times.append(float(allowed))
    roots = [plan.runs, *(Path(o).resolve() / "runs" for o in others)]
    for pair in plan.pairs:
        for job in plan.evaluation_jobs(pair, method):
            if job.run_dir is None:
                continue
            rel = job.run_dir.relative_to(plan.runs)
            for root in roots:
                config = root / rel / "config.json"
                if config.is_file():
                    times.append(config.stat().st_mtime)
    return min(times) if times else None


@dataclass
class Gate:
    """What :func:`check_gate` decided: the selections to use (``fixed``: the protocol's
    ``--selection-from`` ones with each pre-registration's added) and each gated method's
    status, for :func:`write_record`."""

    fixed: dict[str, dict[str, Any]]
    status: dict[str, dict[str, Any]]


def check_gate(
    pairs: Sequence[str],
    methods: Sequence[str],
    budget: str,
    out: Path | str,
    fixed: Mapping[str, Mapping[str, Any]] | None,
    files: Sequence[Path | str] = (),
    exploratory: bool = False,
    stages_from: Sequence[Path | str] = (),
) -> Gate:
    """Check each gated method (:func:`gated_methods`) of a protocol against its
    pre-registration among ``files`` (one file a method; module docstring), before any
    work. Raises PvedError (one line) for a gated method without a valid file, unless
    ``exploratory`` (the method is then marked exploratory, and why is printed), and for
    a file that names no gated method of the protocol."""
    merged: dict[str, Any] = {p: dict(m) for p, m in (fixed or {}).items()}
    gated = gated_methods(methods, budget)
    by_method: dict[str, tuple[Path, dict[str, Any]]] = {}
    for f in map(Path, files):
        data = read_file(f)
        if data["method"] not in gated:
            raise PvedError(
                f"--preregistration {f}: {data['method']} is not a method beyond the paper "
                f"that this protocol evaluates at the paper's budget ({budget})"
            )
        if data["method"] in by_method:
            raise PvedError(f"--preregistration: two files for {data['method']}")
        by_method[data["method"]] = (f, data)
    status: dict[str, dict[str, Any]] = {}
    for method in gated:
        if method not in by_method:
            if not exploratory:
                raise PvedError(
                    f"{method} is beyond the paper and the {budget} budget evaluates it: give "
                    "--preregistration FILE (committed before its evaluation runs start; "
                    "docs/decisions/protocol.md) or --exploratory"
                )
            status[method] = {"status": EXPLORATORY, "why": "no pre-registration given"}
            continue
        path, data = by_method[method]
        try:
            commit, when = committed(path)
            _check_design(path, data, pairs, budget)
            trial = {p: {m: dict(s) for m, s in ms.items()} for p, ms in merged.items()}
            _selection(path, data, pairs, trial)
            plan = ProtocolPlan(pairs, methods, budget, Path(out), trial)
            _check_run_config(path, data, plan, method)
            started = evaluation_started(plan, method, stages_from)
            if started is not None and when >= started:
                raise PvedError(
                    f"--preregistration {path}: committed {_iso(when)} ({commit[:12]}), not "
                    f"before {method}'s first evaluation run started ({_iso(started)})"
                )
            _check_code(path, data)
        except PvedError as exc:
            if not exploratory:
                raise
            print(f"{exc}; {method} runs as {EXPLORATORY}", file=sys.stderr)
            status[method] = {"status": EXPLORATORY, "why": str(exc)}
            continue
        merged = trial
        status[method] = {
            "status": PREREGISTERED,
            "file": record_path(path),
            "commit": commit,
            "committed": _iso(when),
        }
    return Gate(fixed=merged, status=status)


def _iso(when: float) -> str:
    return datetime.datetime.fromtimestamp(when, datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def write_record(out: Path | str, gate: Gate) -> None:
    """``OUT/preregistration.json``: each gated method's status, and when its evaluation
    runs were first let start (kept from an earlier run of the protocol, else now),
    written atomically before the runs can start."""
    if not gate.status:
        return
    earlier = _record(Path(out)).get("evaluation_allowed_at", {})
    now = time.time()
    allowed = {m: earlier.get(m, now) for m in gate.status}
    atomic_write_json(
        Path(out) / RECORD,
        {"methods": gate.status, "evaluation_allowed_at": {**earlier, **allowed}},
    )


def mark_summary(out: Path | str, methods: dict[str, dict[str, Any]]) -> None:
    """A pair's summary entries (``methods``), in place: a gated method's ``exploratory``
    (True) or ``preregistration`` (file, commit, when), from ``OUT/preregistration.json``."""
    for method, state in (_record(Path(out)).get("methods") or {}).items():
        entry = methods.get(method)
        if not isinstance(entry, dict) or not isinstance(state, dict):
            continue
        if state.get("status") == EXPLORATORY:
            entry[EXPLORATORY] = True
        elif state.get("status") == PREREGISTERED:
            entry["preregistration"] = {k: state.get(k) for k in ("file", "commit", "committed")}
