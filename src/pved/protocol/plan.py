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
source's full reward; ``ppo-aa``: ``ppo`` again, the A/A check) have nothing to tune and
no source; each evaluation seed s is run as seeds s, s+1, ..., one per source policy
(``ppo-aa``: s + 10000, s + 10001, ..., :func:`reference_seed`), so every method has the
same number of independent runs. "Does best" is the mean over tuning seeds of the pair's metric
(success rate, or distance along x), ties broken by the mean final return.

Every stage is an ordinary run directory under ``OUT/runs`` (policies the package does
not ship are trained first), so ``pved protocol`` again after an interruption reuses
what finished and resumes the rest; the stages before the transfer runs do not depend
on the budget's steps per run, so another protocol's may be copied in first
(:func:`copy_stage_runs`, ``--stages-from``). ``protocol.json`` records the plan;
:func:`summarize` rebuilds the selection, ``summary.json``/``summary.md`` and the curves
from the run files alone (``pved plot``).

One module past 600 lines on purpose: the plan is one job graph, a pure function of
finished results (tuning, selection and evaluation are its three steps), and its
selection helpers serve it alone.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.curves import read_eval_points
from pved.analysis.run_curves import auc
from pved.config import PRETRAINED, TRAINED, ProtocolBudget, get_budget
from pved.errors import PvedError
from pved.experiments.stages import build_bank, collect_pairs, train_model, train_policy, transfer
from pved.experiments.transfer_spec import eq10_config
from pved.pair import Pair, resolve_pair
from pved.pretrained import pretrained_policy_path, shipped_seeds
from pved.protocol.runner import Job, read_job_result
from pved.record_paths import record_path
from pved.rl.ppo import CHECKPOINT_SECONDS, check_checkpoint_seconds
from pved.run_layout import transfer_run_name
from pved.runs import run_path
from pved.spec import preset_for_agent
from pved.transfer.methods import AA_REFERENCE, REFERENCE_METHODS, get_method

PLAN_FILE = "protocol.json"


def indexed_policy(
    agent: str, task: str, index: int, runs: Path, pair: Pair | None = None
) -> tuple[Path, int, bool]:
    """The protocol's ``index``-th policy of ``agent`` on ``task`` in ``pair`` (default:
    the first pair the agent is in): where the pair's spec says ``pretrained``, the
    shipped ones in seed order (a seed that missed its bar is not shipped); where it
    names a file (a user's own policy, an SB3 ``.zip``), that file as policy 0; then runs
    under ``runs`` that train the seeds not taken, 0, 1, ..., passing over a seed whose run
    has finished below :data:`SOURCE_BAR` (the planner is asked again after every finished
    job, so the jobs that wait on that policy move to the next seed before they start).
    Returns (policy file, seed, whether it is there already, shipped or given)."""
    preset = preset_for_agent(agent) if pair is None else pair.preset
    choice = preset.agent_env(agent, task).policy
    shipped = shipped_seeds(agent, task) if choice == PRETRAINED else []
    if index < len(shipped):
        return pretrained_policy_path(agent, task, shipped[index]), shipped[index], True
    if choice not in (PRETRAINED, TRAINED):
        if index == 0:
            return Path(choice), 0, True
        shipped = [0]  # the file stands for seed 0; a budget's further policies are trained
    # the trained seeds in order, passing over one that has finished below the bar
    wanted, passed_over = index - len(shipped), 0
    for seed in (s for s in itertools.count() if s not in shipped):
        run_dir = run_path(runs, preset.name, "policy", f"{agent}-{task}", seed)
        if passed_over < MAX_PASSED_OVER and _below_bar(run_dir, preset.metric):
            passed_over += 1
            continue
        if wanted == 0:
            return run_dir / "policy.pt", seed, False
        wanted -= 1
    raise AssertionError("unreachable: the seeds never end")


SOURCE_BAR = 0.5
"""A policy the protocol trains is used only where its own evaluation succeeds at least
this often (pairs whose metric is a success rate; the shipped policies had their own
bars): a source that fails its own task has nothing to transfer (issue 64: reacher's
trained source 2 never succeeded at Push). A seed below it is passed over for the next."""
MAX_PASSED_OVER = 5
"""Seeds of one agent and task passed over at most; past them the next seed is used as it
is (the summary names a source that fails its own task)."""


def _below_bar(run_dir: Path, metric: str) -> bool:
    """Whether the policy run in ``run_dir`` has finished with its own evaluation's
    success rate below :data:`SOURCE_BAR` (False while it is not finished, and for a
    metric that is not a success rate)."""
    if metric != "success_rate":
        return False
    result = read_job_result(run_dir)
    rate = result.get("eval/success_rate") if isinstance(result, dict) else None
    return isinstance(rate, int | float) and rate < SOURCE_BAR


@dataclass(frozen=True)
class Candidate:
    """One tuning configuration of a method and its score on the tuning seeds."""

    beta: float
    init: int
    # each tuning seed's run's score: its final metric, or the normalised area under its
    # curve of the metric where the budget selects by it (ProtocolBudget.select_by)
    scores: tuple[float, ...]
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


AA_SEED_OFFSET = 10_000
"""``ppo-aa``'s seeds lie this far above ``ppo``'s: the evaluation seeds are multiples of
20,000 (tuning seeds at most 10,000), so s + 10,000 + k (k < 3 source policies) is an odd
multiple of 10,000 plus k, a seed no other method of any budget uses."""


def reference_seed(method: str, seed: int, k: int) -> int:
    """The PPO seed of reference ``method``'s run for evaluation seed ``seed`` and source
    policy ``k`` (a reference has no source; k only numbers its extra runs): s + k, and
    for the A/A set (:data:`pved.transfer.methods.AA_REFERENCE`) s + :data:`AA_SEED_OFFSET` + k,
    so that its runs share no seed with ``ppo``'s (nor the oracle's)."""
    return seed + k + (AA_SEED_OFFSET if method == AA_REFERENCE else 0)


class ProtocolPlan:
    """The job graph of the protocol for some pairs and methods (a runner ``Planner``)."""

    def __init__(
        self,
        pairs: Sequence[str],
        methods: Sequence[str],
        budget: str,
        out: Path,
        fixed: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None,
        *,
        checkpoint_seconds: float | None = CHECKPOINT_SECONDS,
    ) -> None:
        if not pairs:
            raise PvedError("protocol needs at least one pair")
        if not methods:
            raise PvedError("protocol needs at least one method")
        # each pair resolved once, here (an unknown one fails with the known ones); the
        # jobs carry its name, which the stages resolve again in their own process
        runs = Path(out).resolve() / "runs"
        self.resolved = {pair: resolve_pair(pair, runs) for pair in pairs}
        for method in methods:
            get_method(method)  # an unknown name fails here with the known ones
        if len(set(methods)) != len(methods) or len(set(pairs)) != len(pairs):
            raise PvedError("protocol: a pair or method is named twice")
        self.pairs = list(pairs)
        self.methods = list(methods)
        self.budget: ProtocolBudget = get_budget(budget)
        self.out = Path(out).resolve()
        self.runs = runs
        # what each selection chose, filled in by expand() as results arrive
        self.selection: dict[str, dict[str, Any]] = {}
        # selections made elsewhere (fixed_selections): pair -> method -> beta, init, ...
        self.fixed = relative_selections(fixed or {})
        # each RL run's checkpoints by wall time (``--checkpoint-seconds``): how much a
        # kill or a lost node costs it; not in any run's config, nor in the plan file
        self._run_options = {
            "checkpoint_every_s": check_checkpoint_seconds(
                checkpoint_seconds, "--checkpoint-seconds"
            )
        }

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
            "transfer_steps": {
                p: self._pair(p).preset.transfer_steps(b.steps_budget) for p in self.pairs
            },
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

    def _pair(self, pair: str) -> Pair:
        """``pair`` resolved, its runs under the protocol's ``runs/``."""
        return self.resolved[pair]

    def _dataset_path(self, pair: str) -> Path:
        resolved = self._pair(pair)
        return resolved.runs.dataset(resolved.preset.pairing.align)

    @property
    def model_methods(self) -> list[str]:
        return [m for m in self.methods if get_method(m).shaped]

    def _grid(self, pair: str, method: str) -> tuple[float, ...]:
        preset = self._pair(pair).preset
        own = get_method(method).beta_grid
        # the pair's grid for the method where it sets one, else the method's own scale
        if own is not None and method not in dict(preset.method_beta_grids):
            grid = own
        else:
            grid = preset.beta_grid_for(method)
        size = self.budget.beta_grid_size
        return grid if size is None else grid[:size]

    def _policy(self, pair: str, agent: str, task: str, index: int) -> tuple[Path, Job | None]:
        """The ``index``-th policy of ``agent`` on ``task`` in ``pair``
        (:func:`indexed_policy`), with the job that trains it where it is not there."""
        path, seed, shipped = indexed_policy(agent, task, index, self.runs, self._pair(pair))
        if shipped:
            return path, None
        preset = self._pair(pair).preset
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
                # by name: a worker elsewhere finds a spec pair's agent only through it
                "pair": pair,
            },
            steps=steps,
            run_dir=run_dir,
            run_options=self._run_options,
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
        preset = self._pair(pair).preset
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
                model_path=self._pair(pair).runs.model(self._model(method), init),
                bank_path=self._bank_path(pair, source),
            )
        kwargs["run_name"] = name
        # the selection waits on the tuning runs, and everything on the stages before
        # them (priority 0); evaluation runs fill the workers left over
        tuning = method not in REFERENCE_METHODS and seed in b.tuning_seeds
        # a shaped run made before Eq. 10's fixes (restored or copied) is made again
        required = {} if method in REFERENCE_METHODS else eq10_config(preset.pairing.align)
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
            run_options=self._run_options,
        )

    def _bank_path(self, pair: str, source: int) -> Path:
        preset = self._pair(pair).preset
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
                "dataset": self._dataset_path(pair),
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
        preset = self._pair(pair).preset
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
            self._transfer_job(pair, method, reference_seed(method, seed, k), source=k)
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
        src_train, src_job = self._policy(pair, preset.source_agent, preset.training_task, 0)
        tgt_train, tgt_job = self._policy(pair, preset.target_agent, preset.training_task, 0)
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
                run_dir=self._dataset_path(pair).parent,
                end_product=False,  # read only by the models
            )
        )
        assert pairs_key is not None
        bank_keys: list[str] = []
        for k in range(b.source_policies):
            path, policy_job = self._policy(pair, preset.source_agent, preset.target_task, k)
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
            if b.select_by != "final":  # only then, so earlier selections read as before
                state["select_by"] = b.select_by
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
                beta_candidates = _candidates(tuning, results, preset.metric, b.select_by)
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
            scored = _candidates(tuning, results, preset.metric, b.select_by)
            init_candidates = [c for c in scored if c.beta == chosen_beta]
            state["candidates"] = [dataclasses.asdict(c) for c in scored]
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
                self._transfer_job(pair, method, reference_seed(method, s, k), source=k)
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
            preset = self._pair(pair).preset
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
                    _, job = self._policy(pair, agent, task, index)
                    total += job.steps if job else 0
        return total


def _candidates(
    groups: Mapping[tuple[float, int], Sequence[Job]],
    results: Mapping[str, Any],
    metric: str,
    select_by: str = "final",
) -> list[Candidate]:
    """The candidates whose tuning runs have all finished, in the groups' order, each
    scored by ``select_by`` (:attr:`~pved.config.ProtocolBudget.select_by`) of ``metric``."""
    out: list[Candidate] = []
    for (beta, init), jobs in groups.items():
        if not all(j.key in results for j in jobs):
            continue
        if select_by == "auc":
            scores = tuple(_curve_area(j, metric) for j in jobs)
        else:
            scores = tuple(float(results[j.key][f"final/{metric}"]) for j in jobs)
        returns = tuple(float(results[j.key]["final/return_mean"]) for j in jobs)
        out.append(Candidate(beta=beta, init=init, scores=scores, returns=returns))
    return out


def _curve_area(job: Job, metric: str) -> float:
    """The normalised area under a finished tuning run's learning curve of ``metric``
    (:func:`pved.analysis.run_curves.auc`), read from its ``metrics.jsonl``."""
    assert job.run_dir is not None  # a transfer job always has its run directory
    path = job.run_dir / "metrics.jsonl"
    if not path.is_file():
        raise PvedError(f"{job.key}: no learning curve to score its area ({path} is missing)")
    steps, values = read_eval_points(path, f"eval/{metric}")
    if not steps.size:
        raise PvedError(f"{job.key}: no eval/{metric} points in {path}")
    return auc(steps, values)


def plan_entry(protocol_dir: Path, key: str) -> Any:
    """Entry ``key`` of a protocol directory's plan file (None where unreadable)."""
    try:
        return json.loads((protocol_dir / PLAN_FILE).read_text()).get(key)
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return None


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
    plan = plan_entry(directory, "budget")
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
                "protocol": record_path(directory),
                "budget": str(plan.get("name")),
                "tuning_seeds": tuning,
                "candidates": state.get("candidates", []),
            }
    return fixed


def relative_selections(fixed: Mapping[str, Any]) -> dict[str, Any]:
    """``fixed`` (:func:`fixed_selections`) with the protocol each selection was made in
    as a relative path (:func:`pved.record_paths.record_path`): a plan written before
    paths in records were relative names it by this machine's absolute path. Entries of
    another shape are left as they are, for the plan's own checks to refuse."""

    def relative(state: Any) -> Any:
        if isinstance(state, Mapping) and isinstance(state.get("protocol"), str):
            return {**state, "protocol": record_path(state["protocol"])}
        return dict(state) if isinstance(state, Mapping) else state

    return {
        pair: {m: relative(s) for m, s in methods.items()}
        if isinstance(methods, Mapping)
        else methods
        for pair, methods in fixed.items()
    }


def relative_plan(plan: Mapping[str, Any]) -> dict[str, Any]:
    """A ``protocol.json`` as this version writes it (:func:`relative_selections`), its
    earlier plans too: what a restart compares and what a summary or archive copies."""
    out = dict(plan)
    if isinstance(out.get("selection_from"), dict):
        out["selection_from"] = relative_selections(out["selection_from"])
    if isinstance(out.get("earlier_plans"), list):
        out["earlier_plans"] = [
            relative_plan(p) if isinstance(p, dict) else p for p in out["earlier_plans"]
        ]
    return out


def finished_results(plan: ProtocolPlan) -> dict[str, Any]:
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
