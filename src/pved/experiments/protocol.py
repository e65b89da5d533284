"""The paper's experimental protocol (IV.A, "Parameter-tuning and performance evaluation")
as one job graph: ``pved protocol``.

For each pair and each shaping method (a model name: ``pved``, a variant, ``gupta2017``):

1. beta (Gupta's alpha) is chosen on the tuning seeds with model initialisation 0 and
   source policy 0, from the pair's grid (``PairPreset.beta_grid_for``), searching a
   decade further while the best beta is at the end of what was tried (up to the
   budget's ``beta_grid_extensions`` decades past the grid);
2. the chosen beta is applied to model initialisations 1, 2, ... on the same seeds, and
   the initialisation that does best is kept (init 0's runs at that beta count too);
3. the kept model and beta are evaluated on every evaluation seed with every source
   policy (3 x 5 = 15 runs at the paper budget).

Steps 1 and 2 may instead be taken from another protocol's finished selection
(``--selection-from``, :func:`fixed_selections`): a method screened at the ``quick``
budget is then evaluated at the ``paper`` budget without its 25 tuning runs there, with
the β and model initialisation chosen on the screen's tuning seeds (never on evaluation
seeds; the summary says where each selection was made).

The reference methods (``ppo``: the target's restricted reward alone; ``oracle``: the
source's full reward) have nothing to tune and no source; each evaluation seed s is run
as seeds s, s+1, ..., one per source policy, so every method has the same number of
independent runs. "Does best" is the mean over tuning seeds of the pair's metric
(success rate, or distance along x), ties broken by the mean final return.

Every stage is an ordinary run directory under ``OUT/runs`` (policies the package does
not ship are trained first), so ``pved protocol`` again after an interruption reuses
what finished and resumes the rest; the stages before the transfer runs do not depend
on the budget's steps per run, so another protocol's may be copied in first
(:func:`copy_stage_runs`, ``--stages-from``). ``protocol.json`` records the plan;
:func:`summarize` rebuilds the selection, ``summary.json``/``summary.md`` and the curves
from the run files alone (``pved plot``).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import re
import shutil
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pved import __version__
from pved.checks import check_int, check_writable
from pved.config import ProtocolBudget, get_budget
from pved.errors import PvedError
from pved.experiments.inputs import default_dataset_path, default_model_path
from pved.experiments.runner import (
    Job,
    RunnerReport,
    check_reachable,
    read_job_result,
    resolve_backend,
    run_jobs,
)
from pved.experiments.stages import build_bank, collect_pairs, train_model, train_policy, transfer
from pved.experiments.transfer_spec import eq10_config
from pved.models.train import shared_subspace_collapsed
from pved.pretrained import pretrained_policy_path, shipped_seeds
from pved.runs import atomic_write_bytes, atomic_write_json, repoint_result, run_path
from pved.spec import get_preset, preset_for_agent
from pved.transfer.methods import NO_TRANSFER, ORACLE, REFERENCE_METHODS, get_method

if TYPE_CHECKING:
    from pved.analysis.curves import Panel

PLAN_FILE = "protocol.json"


def indexed_policy(agent: str, task: str, index: int, runs: Path) -> tuple[Path, int, bool]:
    """The protocol's ``index``-th policy of ``agent`` on ``task``: the shipped ones in seed
    order (a seed that missed its bar is not shipped), then runs under ``runs`` that train
    the seeds not shipped, 0, 1, ... Returns (policy file, seed, whether it is shipped)."""
    shipped = shipped_seeds(agent, task)
    if index < len(shipped):
        return pretrained_policy_path(agent, task, shipped[index]), shipped[index], True
    unshipped = (s for s in itertools.count() if s not in shipped)
    seed = next(itertools.islice(unshipped, index - len(shipped), None))
    preset = preset_for_agent(agent)
    run_dir = run_path(runs, preset.name, "policy", f"{agent}-{task}", seed)
    return run_dir / "policy.pt", seed, False


@dataclass(frozen=True)
class Candidate:
    """One tuning configuration of a method and its score on the tuning seeds."""

    beta: float
    init: int
    scores: tuple[float, ...]  # the metric of each tuning seed's run
    returns: tuple[float, ...]  # the final return of each (the tie-breaker)

    def key(self, resolution: float | None = None) -> tuple[float, float]:
        """(mean score, mean return), the score rounded to a multiple of ``resolution``
        when one is given."""
        score = float(np.mean(self.scores))
        if resolution:
            score = float(round(score / resolution))
        return (score, float(np.mean(self.returns)))


def _best(candidates: Sequence[Candidate], resolution: float | None = None) -> Candidate:
    """The candidate with the highest mean score (then mean return); the first on ties,
    so the grid's order decides a complete tie. Mean scores that round to the same
    multiple of ``resolution`` (the preset's ``metric_resolution``) are ties."""
    best = candidates[0]
    for cand in candidates[1:]:
        if cand.key(resolution) > best.key(resolution):
            best = cand
    return best


def _next_decade(
    grid: Sequence[float], tried: Sequence[float], best: float, extensions: int
) -> float | None:
    """The beta to try next when ``best`` is the largest (smallest) beta tried: ten times
    it (a tenth), unless that is more than ``extensions`` decades past the grid's end;
    None when ``best`` lies inside what was tried or the limit is reached. A chosen beta
    at the edge of the search says the optimum may lie beyond it (paper IV.A tunes beta
    per method and task without printing a grid; docs/decisions.md)."""
    if best >= max(tried) and best * 10 <= max(grid) * 10**extensions * (1 + 1e-9):
        return float(f"{best * 10:.12g}")
    if best <= min(tried) and best / 10 >= min(grid) / 10**extensions * (1 - 1e-9):
        return float(f"{best / 10:.12g}")
    return None


def _betas_beyond(
    grid: Sequence[float],
    candidates: Sequence[Candidate],
    extensions: int,
    resolution: float | None = None,
) -> list[float]:
    """The betas to try next after ``candidates`` (one per beta tried, init 0): the next
    decade past the edge where the best one lies (:func:`_next_decade`), or, when every
    candidate ties with every other (score and return: e.g. all zero on a sparse task,
    where nothing points either way), the next decade past both edges. Empty when the
    search is done."""
    tried = [c.beta for c in candidates]
    keys = {c.key(resolution) for c in candidates}
    edges: tuple[float, ...]
    if len(candidates) > 1 and len(keys) == 1:
        edges = (max(tried), min(tried))
    else:
        edges = (_best(candidates, resolution).beta,)
    beyond = (_next_decade(grid, tried, edge, extensions) for edge in edges)
    return [beta for beta in beyond if beta is not None]


def transfer_run_name(method: str, beta: float, init: int, source: int) -> str:
    """The run directory name of a shaped method's transfer run in a protocol:
    ``<method>-beta<β>-init<model init>-src<source policy>`` (one ``seed<k>`` below it
    per PPO seed)."""
    return f"{method}-beta{beta:g}-init{init}-src{source}"


_SHAPED_RUN_NAME = re.compile(r"^(?P<method>.+)-beta[^/]+-init\d+-src\d+$")


def transfer_run_method(name: str) -> str:
    """The method of a transfer run directory name: the ``<method>`` of
    :func:`transfer_run_name`'s, else the name itself (``ppo``, ``oracle``)."""
    match = _SHAPED_RUN_NAME.match(name)
    return match["method"] if match else name


class ProtocolPlan:
    """The job graph of the protocol for some pairs and methods (a runner ``Planner``)."""

    def __init__(
        self,
        pairs: Sequence[str],
        methods: Sequence[str],
        budget: str,
        out: Path,
        fixed: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None,
    ) -> None:
        if not pairs:
            raise PvedError("protocol needs at least one pair")
        if not methods:
            raise PvedError("protocol needs at least one method")
        for pair in pairs:
            get_preset(pair)
        for method in methods:
            get_method(method)  # an unknown name fails here with the known ones
        if len(set(methods)) != len(methods) or len(set(pairs)) != len(pairs):
            raise PvedError("protocol: a pair or method is named twice")
        self.pairs = list(pairs)
        self.methods = list(methods)
        self.budget: ProtocolBudget = get_budget(budget)
        self.out = Path(out).resolve()
        self.runs = self.out / "runs"
        # what each selection chose, filled in by expand() as results arrive
        self.selection: dict[str, dict[str, Any]] = {}
        # selections made elsewhere (fixed_selections): pair -> method -> beta, init, ...
        self.fixed = {p: dict(m) for p, m in (fixed or {}).items()}

    # -- plan file -------------------------------------------------------------------

    def describe(self) -> dict[str, Any]:
        """The plan as written to ``protocol.json`` (what a restart must match)."""
        b = self.budget
        budget = dataclasses.asdict(b)
        if budget["steps_of"] is None:
            # newer than the plans of running protocols: left out where unused, so that
            # their protocol.json still matches and they resume
            del budget["steps_of"]
        plan = {
            "pairs": self.pairs,
            "methods": self.methods,
            "budget": budget,
            "transfer_steps": {p: get_preset(p).transfer_steps(b.steps_budget) for p in self.pairs},
            "beta_grids": {
                p: {m: list(self._grid(p, m)) for m in self.model_methods} for p in self.pairs
            },
        }
        if self.fixed:  # only where used, so that the plans of earlier protocols still match
            plan["selection_from"] = self.fixed
        return plan

    @classmethod
    def load(cls, out: Path) -> ProtocolPlan:
        """The plan of an existing protocol directory."""
        path = Path(out) / PLAN_FILE
        try:
            plan = json.loads(path.read_text())
            return cls(
                plan["pairs"],
                plan["methods"],
                plan["budget"]["name"],
                Path(out),
                plan.get("selection_from"),
            )
        except FileNotFoundError:
            raise PvedError(f"{out} is not a protocol directory (no {PLAN_FILE})") from None
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise PvedError(f"{path} is not a readable protocol plan ({err})") from None

    # -- pieces ----------------------------------------------------------------------

    @property
    def model_methods(self) -> list[str]:
        return [m for m in self.methods if get_method(m).shaped]

    def _grid(self, pair: str, method: str) -> tuple[float, ...]:
        preset = get_preset(pair)
        own = get_method(method).beta_grid
        # the pair's grid for the method where it sets one, else the method's own scale
        if own is not None and method not in dict(preset.method_beta_grids):
            grid = own
        else:
            grid = preset.beta_grid_for(method)
        size = self.budget.beta_grid_size
        return grid if size is None else grid[:size]

    def _policy(self, agent: str, task: str, index: int) -> tuple[Path, Job | None]:
        """The ``index``-th policy of ``agent`` on ``task`` (:func:`indexed_policy`), with
        the job that trains it where it is not shipped."""
        path, seed, shipped = indexed_policy(agent, task, index, self.runs)
        if shipped:
            return path, None
        preset = preset_for_agent(agent)
        run_dir = path.parent
        steps = self.budget.policy_steps or preset.policy_config(agent, task).total_steps
        job = Job(
            key=f"policy/{agent}-{task}/seed{seed}",
            fn=train_policy,
            kwargs={
                "agent": agent,
                "task": task,
                "seed": seed,
                "steps": self.budget.policy_steps,
                "runs_root": self.runs,
                "progress": False,
            },
            steps=steps,
            run_dir=run_dir,
        )
        return run_dir / "policy.pt", job

    def _transfer_job(
        self,
        pair: str,
        method: str,
        seed: int,
        *,
        beta: float | None = None,
        init: int = 0,
        source: int = 0,
        deps: tuple[str, ...] = (),
    ) -> Job:
        preset = get_preset(pair)
        b = self.budget
        steps = preset.transfer_steps(b.steps_budget)
        kwargs: dict[str, Any] = {
            "pair": pair,
            "method": method,
            "seed": seed,
            "steps": steps,
            "eval_every": b.eval_every,
            "eval_episodes": b.eval_episodes,
            "final_eval_episodes": b.final_eval_episodes,
            "runs_root": self.runs,
            "progress": False,
        }
        if method in REFERENCE_METHODS:
            name = method
        else:
            assert beta is not None
            name = transfer_run_name(method, beta, init, source)
            kwargs.update(
                beta=beta,
                model_path=default_model_path(pair, self._model(method), self.runs, seed=init),
                bank_path=self._bank_path(pair, source),
            )
        kwargs["run_name"] = name
        # the selection waits on the tuning runs, and everything on the stages before
        # them (priority 0); evaluation runs fill the workers left over
        tuning = method not in REFERENCE_METHODS and seed in b.tuning_seeds
        # a shaped run made before Eq. 10's fixes (restored or copied) is made again
        required = {} if method in REFERENCE_METHODS else eq10_config(pair)
        return Job(
            key=f"{pair}/transfer/{name}/seed{seed}",
            fn=transfer,
            kwargs=kwargs,
            deps=deps,
            priority=1 if tuning else 2,
            steps=steps,
            run_dir=run_path(self.runs, pair, "transfer", name, seed),
            tags={"source_policy": source, "init": init, "beta": beta},
            required_config=required,
        )

    def _bank_path(self, pair: str, source: int) -> Path:
        preset = get_preset(pair)
        name = f"{preset.source_agent}-{preset.target_task}"
        return run_path(self.runs, pair, "bank", name, source) / "bank.npz"

    @staticmethod
    def _model(method: str) -> str:
        """The model whose shared space ``method`` shapes with: methods naming the same
        model share its runs (``pved`` and ``pved-potential`` train one PVED)."""
        model = get_method(method).model
        assert model is not None, method
        return model

    def _model_job(self, pair: str, method: str, init: int, deps: tuple[str, ...]) -> Job:
        method = self._model(method)
        return Job(
            key=f"{pair}/model/{method}/init{init}",
            fn=train_model,
            kwargs={
                "pair": pair,
                "model": method,
                "dataset": default_dataset_path(pair, self.runs),
                "seed": init,
                "epochs": self.budget.model_epochs,
                "runs_root": self.runs,
                "progress": False,
            },
            deps=deps,
            run_dir=run_path(self.runs, pair, "model", method, init),
            # made for its transfer runs; the selected one is marked an end product when
            # it is chosen (the summary reads its validation metrics)
            end_product=False,
        )

    # -- the graph ---------------------------------------------------------------------

    def expand(self, results: Mapping[str, Any]) -> list[Job]:
        """Every job definable from ``results``; records selections as they are made."""
        jobs: list[Job] = []
        for pair in self.pairs:
            jobs.extend(self._expand_pair(pair, results))
        return jobs

    def _expand_pair(self, pair: str, results: Mapping[str, Any]) -> list[Job]:
        preset = get_preset(pair)
        b = self.budget
        jobs: list[Job] = []
        seen: set[str] = set()

        def add(job: Job | None) -> str | None:
            if job is None:
                return None
            if job.key not in seen:
                seen.add(job.key)
                jobs.append(job)
            return job.key

        eval_jobs = [
            self._transfer_job(pair, method, seed + k, source=k)
            for method in self.methods
            if method in REFERENCE_METHODS
            for k in range(b.source_policies)
            for seed in b.evaluation_seeds
        ]
        for job in eval_jobs:
            add(job)
        if not self.model_methods:
            return jobs

        # the earlier stages: training-task policies, pairs, banks of each source policy
        src_train, src_job = self._policy(preset.source_agent, preset.training_task, 0)
        tgt_train, tgt_job = self._policy(preset.target_agent, preset.training_task, 0)
        policy_deps = tuple(k for k in (add(src_job), add(tgt_job)) if k)
        pairs_key = add(
            Job(
                key=f"{pair}/pairs",
                fn=collect_pairs,
                kwargs={
                    "pair": pair,
                    "source_policy": src_train,
                    "target_policy": tgt_train,
                    "episodes": b.pair_episodes,
                    "runs_root": self.runs,
                    "progress": False,
                },
                deps=policy_deps,
                run_dir=default_dataset_path(pair, self.runs).parent,
                end_product=False,  # read only by the models
            )
        )
        assert pairs_key is not None
        bank_keys: list[str] = []
        for k in range(b.source_policies):
            path, policy_job = self._policy(preset.source_agent, preset.target_task, k)
            dep = add(policy_job)
            bank_key = add(
                Job(
                    key=f"{pair}/bank/src{k}",
                    fn=build_bank,
                    kwargs={
                        "pair": pair,
                        "source_policy": path,
                        "episodes": b.bank_episodes,
                        "seed": k,
                        "runs_root": self.runs,
                    },
                    deps=(dep,) if dep else (),
                    run_dir=self._bank_path(pair, k).parent,
                    end_product=False,  # read only by the transfer runs of source k
                )
            )
            assert bank_key is not None
            bank_keys.append(bank_key)

        for method in self.model_methods:
            fixed = self.fixed.get(pair, {}).get(method)
            if fixed is not None:  # chosen in another protocol: no tuning runs here
                self.selection.setdefault(pair, {})[method] = {
                    "beta_grid": [],
                    "candidates": list(fixed.get("candidates", [])),
                    "beta": fixed["beta"],
                    "init": fixed["init"],
                    "selected_in": {k: fixed[k] for k in ("protocol", "budget", "tuning_seeds")},
                }
                model_key = add(self._model_job(pair, method, fixed["init"], (pairs_key,)))
                assert model_key is not None
                self._add_evaluation(pair, method, fixed["beta"], fixed["init"], bank_keys, add)
                continue
            model0 = add(self._model_job(pair, method, 0, (pairs_key,)))
            assert model0 is not None
            grid = self._grid(pair, method)
            state: dict[str, Any] = {"beta_grid": list(grid), "candidates": []}
            self.selection.setdefault(pair, {})[method] = state
            tuning: dict[tuple[float, int], list[Job]] = {}
            tried = list(grid)
            chosen_beta: float | None = None
            while True:
                for beta in tried:
                    if (beta, 0) not in tuning:
                        tuning[(beta, 0)] = [
                            self._transfer_job(
                                pair, method, s, beta=beta, deps=(model0, bank_keys[0])
                            )
                            for s in b.tuning_seeds
                        ]
                        for job in tuning[(beta, 0)]:
                            add(job)
                beta_candidates = _candidates(tuning, results)
                state["candidates"] = [dataclasses.asdict(c) for c in beta_candidates]
                if len(beta_candidates) < len(tried):
                    break
                beyond = _betas_beyond(
                    grid, beta_candidates, b.beta_grid_extensions, preset.metric_resolution
                )
                if not beyond:
                    chosen_beta = _best(beta_candidates, preset.metric_resolution).beta
                    break
                tried.extend(beyond)
            if len(tried) > len(grid):
                state["beta_extended"] = tried[len(grid) :]
            if chosen_beta is None:
                continue
            state["beta"] = chosen_beta
            for init in range(1, b.model_inits):
                model_key = add(self._model_job(pair, method, init, (pairs_key,)))
                assert model_key is not None
                tuning[(chosen_beta, init)] = [
                    self._transfer_job(
                        pair,
                        method,
                        s,
                        beta=chosen_beta,
                        init=init,
                        deps=(model_key, bank_keys[0]),
                    )
                    for s in b.tuning_seeds
                ]
                for job in tuning[(chosen_beta, init)]:
                    add(job)
            init_candidates = [c for c in _candidates(tuning, results) if c.beta == chosen_beta]
            state["candidates"] = [dataclasses.asdict(c) for c in _candidates(tuning, results)]
            if len(init_candidates) < b.model_inits:
                continue
            chosen_init = _best(init_candidates, preset.metric_resolution).init
            state["init"] = chosen_init
            self._add_evaluation(pair, method, chosen_beta, chosen_init, bank_keys, add)
        for i, job in enumerate(jobs):  # the chosen models are end products
            if job.key in self._chosen_models(pair):
                jobs[i] = dataclasses.replace(job, end_product=True)
        return jobs

    def _chosen_models(self, pair: str) -> set[str]:
        """The keys of the models the selections of ``pair`` kept."""
        return {
            f"{pair}/model/{self._model(method)}/init{state['init']}"
            for method, state in self.selection.get(pair, {}).items()
            if state.get("init") is not None
        }

    def _add_evaluation(
        self,
        pair: str,
        method: str,
        beta: float,
        init: int,
        bank_keys: Sequence[str],
        add: Callable[[Job | None], str | None],
    ) -> None:
        """Every evaluation seed x source policy of ``method`` at the chosen β and init."""
        model_key = f"{pair}/model/{self._model(method)}/init{init}"
        for k in range(self.budget.source_policies):
            for s in self.budget.evaluation_seeds:
                add(
                    self._transfer_job(
                        pair,
                        method,
                        s,
                        beta=beta,
                        init=init,
                        source=k,
                        deps=(model_key, bank_keys[k]),
                    )
                )

    def evaluation_jobs(self, pair: str, method: str) -> list[Job]:
        """The evaluation runs of ``method`` on ``pair`` (after its selection is made;
        empty while it is not)."""
        b = self.budget
        if method in REFERENCE_METHODS:
            return [
                self._transfer_job(pair, method, s + k, source=k)
                for k in range(b.source_policies)
                for s in b.evaluation_seeds
            ]
        state = self.selection.get(pair, {}).get(method, {})
        if "init" not in state:
            return []
        return [
            self._transfer_job(pair, method, s, beta=state["beta"], init=state["init"], source=k)
            for k in range(b.source_policies)
            for s in b.evaluation_seeds
        ]

    def expected_steps(self) -> int:
        """Env steps of every RL run of the plan (policies to train included); the beta
        search's steps past the grid count once :meth:`expand` has added them."""
        b = self.budget
        total = 0
        for pair in self.pairs:
            preset = get_preset(pair)
            steps = preset.transfer_steps(b.steps_budget)
            per_eval = b.source_policies * len(b.evaluation_seeds)
            for method in self.methods:
                runs = per_eval
                if method not in REFERENCE_METHODS and method not in self.fixed.get(pair, {}):
                    state = self.selection.get(pair, {}).get(method, {})
                    extended = len(state.get("beta_extended", ()))
                    tuning = len(self._grid(pair, method)) + extended + b.model_inits - 1
                    runs += tuning * len(b.tuning_seeds)
                total += runs * steps
            if self.model_methods:
                needed = [(preset.source_agent, preset.training_task, 0)]
                needed.append((preset.target_agent, preset.training_task, 0))
                needed += [
                    (preset.source_agent, preset.target_task, k) for k in range(b.source_policies)
                ]
                for agent, task, index in needed:
                    _, job = self._policy(agent, task, index)
                    total += job.steps if job else 0
        return total


def _candidates(
    groups: Mapping[tuple[float, int], Sequence[Job]], results: Mapping[str, Any]
) -> list[Candidate]:
    """The candidates whose tuning runs have all finished, in the groups' order."""
    out: list[Candidate] = []
    for (beta, init), jobs in groups.items():
        if not all(j.key in results for j in jobs):
            continue
        pair = jobs[0].kwargs["pair"]
        metric = get_preset(pair).metric
        scores = tuple(float(results[j.key][f"final/{metric}"]) for j in jobs)
        returns = tuple(float(results[j.key]["final/return_mean"]) for j in jobs)
        out.append(Candidate(beta=beta, init=init, scores=scores, returns=returns))
    return out


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


def _plan_entry(protocol_dir: Path, key: str) -> Any:
    """Entry ``key`` of a protocol directory's plan file (None where unreadable)."""
    try:
        return json.loads((protocol_dir / PLAN_FILE).read_text()).get(key)
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return None


def copy_stage_runs(source: Path | str, out: Path | str, pairs: Sequence[str]) -> int:
    """Copy ``source``'s finished policy, pairs, model and bank runs of ``pairs`` into
    protocol directory ``out`` where ``out`` has no run of that name yet; returns how
    many were copied. Where both plans give a pair the same steps per transfer run
    (``paper`` and ``paper-wide``, say), its finished transfer runs of the methods
    ``out``'s plan has are copied too.

    A copied run is used only where its ``config.json`` hash equals the one the plan of
    ``out`` asks for (``Run.is_done``); any other is redone, as an interrupted run
    would be, so a copy can save hours (a locomotion pair's 18 models) but cannot put a
    run made under other settings into the results. Each run is copied to a temporary
    name and renamed, so an interrupted copy leaves nothing that looks finished.
    """
    source, out = _stages_source(source, out), Path(out).resolve()
    source_steps = _plan_entry(source, "transfer_steps") or {}
    out_steps = _plan_entry(out, "transfer_steps") or {}
    out_methods = set(_plan_entry(out, "methods") or ())
    copied = 0
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
                partial = target.with_name(f".{target.name}.copying")
                shutil.rmtree(partial, ignore_errors=True)
                # checkpoints are not needed by a finished run
                shutil.copytree(run, partial, ignore=shutil.ignore_patterns("checkpoints"))
                repoint_result(partial, target)  # its model.pt, not the other protocol's
                partial.rename(target)
                copied += 1
    return copied


def fixed_selections(
    source: Path | str, pairs: Sequence[str], methods: Sequence[str], budget: str
) -> dict[str, dict[str, dict[str, Any]]]:
    """The β and model initialisation that protocol directory ``source`` chose for each
    shaped method of ``methods`` on each of ``pairs`` (its ``selection.json``), with where
    and on which tuning seeds they were chosen, to be evaluated at ``budget`` without
    tuning again (``--selection-from``).

    Raises PvedError (one line) where ``source`` is not a protocol directory, has not
    finished a selection asked for, or tuned on a seed that ``budget`` evaluates on (a
    selection must never see an evaluation seed)."""
    directory = Path(source).resolve()
    plan = _plan_entry(directory, "budget")
    if not isinstance(plan, dict) or not (directory / "selection.json").is_file():
        raise PvedError(
            f"--selection-from {source}: not a protocol directory with a selection.json"
        )
    try:
        chosen = json.loads((directory / "selection.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PvedError(f"{directory / 'selection.json'}: unreadable ({exc})") from None
    tuning = [int(s) for s in plan.get("tuning_seeds", [])]
    overlap = sorted(set(tuning) & set(get_budget(budget).evaluation_seeds))
    if overlap:
        raise PvedError(
            f"--selection-from {source}: it tuned on seeds {overlap} that the {budget} "
            "budget evaluates on"
        )
    fixed: dict[str, dict[str, dict[str, Any]]] = {}
    for pair in pairs:
        for method in methods:
            if not get_method(method).shaped:
                continue
            state = chosen.get(pair, {}).get(method) if isinstance(chosen, dict) else None
            if not isinstance(state, dict) or state.get("init") is None:
                raise PvedError(
                    f"--selection-from {source}: no finished selection of {method} on {pair}"
                )
            fixed.setdefault(pair, {})[method] = {
                "beta": float(state["beta"]),
                "init": int(state["init"]),
                "protocol": str(directory),
                "budget": str(plan.get("name")),
                "tuning_seeds": tuning,
                "candidates": state.get("candidates", []),
            }
    return fixed


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
) -> dict[str, Any]:
    """Run (or resume) the protocol into ``out``; returns ``summary.json``'s content.

    A directory that already holds a protocol must hold the same one (pairs, methods,
    budget): its finished runs are reused and unfinished ones resumed. ``backend``: see
    :func:`pved.experiments.runner.run_jobs`. ``stages_from``: protocol directories (one,
    or several in order) whose finished policies, pairs, models and banks are copied in
    first (:func:`copy_stage_runs`), e.g. the ``quick`` protocol of a pair before its
    ``paper`` one; a run already copied from an earlier one is kept. ``selection_from``:
    a protocol directory whose β and model selections are used instead of tuning here
    (:func:`fixed_selections`)."""
    sources: list[Path | str] = (
        []
        if stages_from is None
        else [stages_from]
        if isinstance(stages_from, str | Path)
        else list(stages_from)
    )
    ProtocolPlan(pairs, methods, budget, Path(out))  # names checked before the selection
    fixed = (
        None if selection_from is None else fixed_selections(selection_from, pairs, methods, budget)
    )
    plan = ProtocolPlan(pairs, methods, budget, Path(out), fixed)
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
            existing = json.loads(plan_path.read_text())
        except json.JSONDecodeError:
            raise PvedError(f"{plan_path} is corrupt; remove it or use another --out") from None
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
    else:
        plan.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(plan_path, {**description, "pved_version": __version__})
    for source in sources:
        copied = copy_stage_runs(source, plan.out, plan.pairs)
        print(f"copied {copied} finished runs from {source}", file=sys.stderr)
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


def _finished_results(plan: ProtocolPlan) -> dict[str, Any]:
    """Results of the plan's jobs read from their run directories, expanding the graph
    until no more finished jobs are found (the selections are remade on the way)."""
    results: dict[str, Any] = {}
    while True:
        added = False
        for job in plan.expand(results):
            if job.key in results or job.run_dir is None:
                continue
            result = read_job_result(job.run_dir, job.required_config)
            if result is not None:
                results[job.key] = result
                added = True
        if not added:
            return results


def pair_panel(
    plan: ProtocolPlan, pair: str, results: Mapping[str, Any], title: str | None = None
) -> Panel | None:
    """The learning curves of every method's finished evaluation runs on ``pair`` (one
    panel of Fig. 3), or None when no method has any."""
    from pved.analysis.curves import Panel, load_curve

    metric = get_preset(pair).metric
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
    results = _finished_results(plan)
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
    for pair in plan.pairs:
        preset = get_preset(pair)
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
                entry["final"] = bootstrap_summary(scores)
                entry["runs"] = [
                    {
                        "key": j.key,
                        "seed": j.kwargs["seed"],
                        "source_policy": j.tags["source_policy"],
                        metric: float(results[j.key][f"final/{metric}"]),
                        "result": str(j.run_dir / "result.json") if j.run_dir else None,
                    }
                    for j in done
                ]
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
        summary["pairs"][pair] = {"metric": metric, "methods": methods}
        if panel is not None:
            panels.append(panel)
            plot_panels([panel], out / f"curves-{pair}.png")
    if panels:
        plot_panels(panels, out / "curves.png")
    atomic_write_json(out / "selection.json", plan.selection)
    atomic_write_json(out / "summary.json", summary)
    atomic_write_bytes(out / "summary.md", _markdown(summary, plan).encode())
    return summary, panels


def _fmt(x: float | None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return f"{x:.{digits}f}"


def _with_ci(value: float, ci: Sequence[float]) -> str:
    return f"{_fmt(value)} [{_fmt(ci[0])}, {_fmt(ci[1])}]"


def _scale_cells(method_summary: Mapping[str, Any], method: str) -> tuple[str, str]:
    """The summary table's two reward-scale cells of one method (``–`` without a shaping
    term; ``none`` for the align form, which pays none): the Eq. 10 term with its
    distance D (a KL in nats, or a point-code model's squared distance; only for the
    ``eq10`` form, where D = term / −β) and the env's reward, each at the first and last
    rollout."""
    scale = method_summary.get("reward_scale")
    if not scale:
        return "–", "–"
    first, last = scale["shaping_first"], scale["shaping_last"]
    shaping = f"{first:.3g} → {last:.3g}"
    if get_method(method).shaping_form == "align":  # its term is in the loss, not the reward
        shaping = "none (a loss on the mean action)"
    beta = method_summary.get("beta")
    if isinstance(beta, int | float) and beta > 0 and get_method(method).shaping_form == "eq10":
        shaping += f" (D {-first / beta:,.4g} → {-last / beta:,.4g})"
    env = f"{scale['env_reward_first']:.3g} → {scale['env_reward_last']:.3g}"
    return shaping, env


def _markdown(summary: Mapping[str, Any], plan: ProtocolPlan) -> str:
    from pved.analysis.curves import reach_cell

    b = plan.budget
    lines = [
        f"# Protocol summary ({b.name} budget)",
        "",
        f"Tuning seeds {list(b.tuning_seeds)}; evaluation seeds {list(b.evaluation_seeds)} "
        f"x {b.source_policies} source policies; {b.model_inits} model initialisations. "
        "Final performance over the evaluation runs: mean and interquartile mean (IQM) "
        "with 95% stratified-bootstrap confidence intervals (rliable).",
        "",
    ]
    for pair, info in summary["pairs"].items():
        metric = info["metric"]
        lines += [
            f"## {pair} ({metric})",
            "",
            f"![curves](curves-{pair}.png)",
            "",
            "| method | runs | mean [95% CI] | IQM [95% CI] | steps to PPO's final "
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
                f"| {method} | {m['runs_finished']}/{m['runs_planned']} | {mean} | {iqm} | "
                f"{reach[0]} | {reach[1]} | {beta} | {init} | {shaping} | {env_reward} |"
            )
        lines.append("")
        for method, state in summary["selection"].get(pair, {}).items():
            lines.append(f"Selection of {method} (mean {metric} over the tuning seeds):")
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
