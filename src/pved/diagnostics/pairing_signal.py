"""Does a pair's paired dataset relate the two agents, and do its models' shared codes?

Eq. 10's reward can only tell a good target step from a bad one if the model's two
encoders put a step and its partner near each other and unrelated steps apart. That takes
two things, and this script measures each for a finished ``pved protocol`` directory:

1. **Signal in the pairing.** How much of one agent's step (robot state and action,
   standardised) a ridge regression predicts from its paired step of the other agent, as
   R² on held-out episodes (every tenth episode), and the same with the partner rows
   shuffled (≈ 0: the floor). Linear, so a lower bound on what the data hold, but the
   scale that separates pairs: if little of the target is predictable from the source,
   the cross terms of Eqs. 2 and 6 have little to carry into c.
2. **What the codes hold.** For each selected Gaussian-c model, the mean KL of each
   encoder's shared posterior from the N(0, I) prior (nats: how much the code says about
   its step; near 0 means it sits on the prior whatever the input), and D of Eq. 10 on
   matched and shuffled training pairs (:mod:`pved.diagnostics.shaping_scale`). Where the protocol
   kept its first source bank (the source's steps on the target task, which the transfer
   runs' Eq. 10 term draws from), the same KL for the bank's steps and D between a bank
   step and an unrelated training target step: how far the target task takes the source's
   codes from the pairs the model was trained on.

``alpha3`` (``--alpha3 A [A ...]``) refits PVED on the same dataset with the consistency
weight α3 of Eq. 9 set to each value (the selected model's config, seed and epochs otherwise) and
measures the refits the same way, to see whether the weight, rather than the data,
holds the codes apart or on the prior. The refits are written under
``PROTOCOL_DIR/subspaces/pairing_signal/`` and reused when the analysis is run again.

    pved analyze pairing-signal reports/humanoid-ant-quick --alpha3 1 0.1

Prints Markdown tables and writes ``PROTOCOL_DIR/subspaces/pairing_signal.json``
(:func:`protocol_pairing_signal`). With ``--datasets A.npz B.npz [--first-episodes N]``
instead (:func:`compare_datasets`), it prints only the first measure for each dataset
(e.g. the same episodes under two alignments) and writes nothing; ``--model M.pt [--bank
B.npz]`` adds the second for one model on each dataset. ``--repair`` adds, for each
dataset, the first measure after re-pairing its rows within each episode
(:data:`REPAIRINGS`): the offline check of pairing by gait phase, with its two controls
(docs/decisions.md, "Pairing by gait phase").

``pved pair signal`` (:func:`pair_signal`) asks the first question before any model is
trained or transfer run is spent on a pair: it collects a few paired episodes of the pair
(its policies on its training task, its alignment; :func:`collect_pairs`) and measures
their held-out R² each way beside the shuffled floor. A pairing that relates the agents
is needed, not enough: on the built-in pairs' full datasets the arms' pairings relate
them strongly (R² 0.70 reacher, 0.72 jaco-fetch) and the legs' weakly (0.14
walker-hopper, 0.09 humanoid-ant), and transfer pays on walker-hopper alone
(docs/journal/across-pairs.md).
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved.analysis.judge import load_summary
from pved.checks import check_int, check_seed
from pved.diagnostics.shaping_audit import distance_stats, matched_and_shuffled
from pved.errors import PvedError
from pved.experiments.stages import collect_pairs
from pved.models.base import SharedSpaceModel
from pved.models.distributions import kl_standard_normal
from pved.models.registry import load_model, save_model
from pved.models.train import train_model
from pved.pair import resolve_pair
from pved.pairing.align import PHASE_WINDOW, first_component, gait_phase, phase_indices
from pved.pairing.dataset import PairedDataset, load_dataset
from pved.runs import atomic_write_json, run_path
from pved.spec import get_preset
from pved.transfer.source_bank import load_bank

HELD_OUT_EVERY = 10  # every tenth episode is held out of the regression's fit
RIDGE = 1e-2  # ridge penalty per training row, on standardised inputs


def _standardised(x: np.ndarray) -> np.ndarray:
    """(M, D) with each column at mean 0 and std 1; constant columns left at 0."""
    std = x.std(0)
    return (x - x.mean(0)) / np.where(std > 1e-8, std, 1.0)


def ridge_r2(x_from: np.ndarray, x_to: np.ndarray, episode: np.ndarray) -> float:
    """Held-out R² of a ridge regression of x_to (M, D_to) on x_from (M, D_from), both
    standardised; rows of every ``HELD_OUT_EVERY``-th episode (episode (M,)) are held out.
    R² is pooled over the output columns that vary on the held-out rows."""
    a = np.concatenate([_standardised(x_from), np.ones((len(x_from), 1))], 1)
    b = _standardised(x_to)
    test = episode % HELD_OUT_EVERY == 0
    fit = a[~test]
    weights = np.linalg.solve(fit.T @ fit + RIDGE * len(fit) * np.eye(a.shape[1]), fit.T @ b[~test])
    residual = ((b[test] - a[test] @ weights) ** 2).sum(0)
    total = ((b[test] - b[test].mean(0)) ** 2).sum(0)
    varies = total > 1e-6
    return float(1.0 - residual[varies].sum() / total[varies].sum())


def pairing_r2(
    x_s: np.ndarray, x_t: np.ndarray, episode: np.ndarray, rows: int, seed: int
) -> dict[str, float]:
    """Held-out ridge R² both ways on ``rows`` seeded samples of the paired rows, and
    source → target with the target rows shuffled."""
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False))
    s, t, e = x_s[pick].astype(np.float64), x_t[pick].astype(np.float64), episode[pick]
    return {
        "source_to_target": ridge_r2(s, t, e),
        "target_to_source": ridge_r2(t, s, e),
        "source_to_shuffled_target": ridge_r2(s, t[rng.permutation(len(t))], e),
    }


@torch.no_grad()
def code_information(
    model: SharedSpaceModel,
    x_s: np.ndarray,
    x_t: np.ndarray,
    rows: int,
    seed: int,
    bank: np.ndarray | None = None,
) -> dict[str, Any]:
    """Mean KL (nats) of each encoder's shared posterior from N(0, I) on ``rows`` seeded
    samples, and D of Eq. 10 matched and shuffled; the KLs are None for a point-code model.

    With ``bank`` (N, D_S), the source's steps on the target task that the transfer runs
    draw from: the same KL for its steps, and D between a bank step and an unrelated
    training target step (``"bank_vs_target"``), to tell whether the target task takes
    the source's codes away from what the model was trained on."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False)
    sides = [("source", x_s[pick]), ("target", x_t[pick])]
    if bank is not None:
        bank = bank[rng.choice(len(bank), size=min(rows, len(bank)), replace=False)]
        sides.append(("bank", bank))
    out: dict[str, Any] = {}
    for side, x in sides:
        encode = model.shared_target if side == "target" else model.shared_source
        rep = encode(torch.as_tensor(x))
        out[f"kl_prior_{side}"] = (
            None
            if rep.logvar is None
            else float(kl_standard_normal(rep.mean, rep.logvar).double().mean())
        )
    out.update(matched_and_shuffled(model, x_s, x_t, rows, seed))
    if bank is not None:
        target = torch.as_tensor(x_t[rng.choice(len(x_t), size=len(bank), replace=False)])
        distance = model.shaping(torch.as_tensor(bank), target).double().numpy()
        out["bank_vs_target"] = distance_stats(distance)
    return out


def bank_rows(path: Path) -> np.ndarray:
    """Every step (N, D_S) of a source bank's episodes, robot state then action."""
    bank = load_bank(path)
    return np.concatenate([bank.x[e, :length] for e, length in enumerate(bank.lengths)])


def refit_alpha3(
    selected: SharedSpaceModel,
    x_s: np.ndarray,
    x_t: np.ndarray,
    state_dims: tuple[int, int],
    alpha3: float,
    out: Path,
) -> SharedSpaceModel:
    """The ``selected`` PVED model refitted on the same rows with only α3 changed (its
    config, seed and epochs kept); loaded from ``out`` when a previous call wrote it from
    the same model and dataset (a protocol that reselected since is refitted anew)."""
    config = dataclasses.replace(selected.config, alpha3=alpha3)  # type: ignore[call-arg]
    if out.is_file():
        earlier = load_model(out).eval()
        same_data = earlier.metadata.get("dataset") == selected.metadata.get("dataset")
        if earlier.config == config and same_data:
            return earlier
    model = train_model("pved", x_s, x_t, config, state_dims=state_dims)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, out, {**selected.metadata, "alpha3": alpha3})
    return model


#: ``--repair``'s re-pairings of a dataset's rows within each episode. Each gives every
#: target row the source row, among the ``PHASE_WINDOW`` rows to either side of its own
#: partner (21 candidates), at the nearest gait phase of each agent's first principal
#: component (``phase``); at the nearest phase of a seeded random direction instead (a
#: control: how much does choosing among 21 on any signal gain?); or drawn uniformly
#: (the other control: how much does moving a partner a few steps cost?).
REPAIRINGS = ("phase", "random-direction phase", "random in window")


def repaired_source_rows(dataset: PairedDataset, how: str, seed: int) -> np.ndarray:
    """The source row (M,) int64 that each target row is paired with after the re-pairing
    ``how`` (a key of :data:`REPAIRINGS`); the rows of an episode are taken in the target's
    time order, and a row never leaves its episode.

    The phase is :func:`pved.pairing.align.gait_phase` of the paired rows' robot state,
    standardised over all rows, projected on the first principal component (or on a
    seeded random unit direction) and taken per episode; the stage does the same on the
    agents' every step, so it has more source candidates than these rows offer."""
    if how not in REPAIRINGS:
        raise PvedError(f"unknown re-pairing {how!r}; known: {', '.join(REPAIRINGS)}")
    rng = np.random.default_rng(seed)
    signals = []
    for obs, idx in ((dataset.obs_source, dataset.robot_indices_source),
                     (dataset.obs_target, dataset.robot_indices_target)):  # fmt: skip
        mean, scale, direction, _ = first_component(obs[:, idx])
        if how != "phase":
            direction = rng.normal(size=len(direction))
            direction /= np.linalg.norm(direction)
        signals.append(((obs[:, idx] - mean) / scale) @ direction)
    source_rows = np.arange(len(dataset), dtype=np.int64)
    for e in np.unique(dataset.episode):
        rows = np.flatnonzero(dataset.episode == e)
        rows = rows[np.argsort(dataset.t_target[rows], kind="stable")]
        local = np.arange(len(rows), dtype=np.int64)
        if how == "random in window":
            lo = np.maximum(local - PHASE_WINDOW, 0)
            hi = np.minimum(local + PHASE_WINDOW, len(rows) - 1)
            chosen = lo + (rng.random(len(rows)) * (hi - lo + 1)).astype(np.int64)
        else:
            phase_s, phase_t = (gait_phase(signal[rows]) for signal in signals)
            chosen = phase_indices(phase_s, phase_t, (local, local))[0]
        source_rows[rows] = rows[chosen]
    return source_rows


def compare_datasets(
    paths: list[Path],
    first_episodes: int | None,
    rows: int,
    code_rows_wanted: int,
    seed: int,
    model_path: Path | None = None,
    bank_path: Path | None = None,
    repair: bool = False,
) -> str:
    """The pairing's R² (:func:`pairing_r2`) of each paired dataset, e.g. the same
    episodes collected under two alignments, restricted to its first episodes if given;
    with ``repair``, also after each of :data:`REPAIRINGS`; with ``model_path``, also that
    model's :func:`code_information` on each dataset (and on the source bank at
    ``bank_path``, if given), as Markdown tables."""
    r2_rows, code_rows = [], []
    model = None if model_path is None else load_model(model_path).eval()
    bank = None if bank_path is None else bank_rows(bank_path).astype(np.float32)
    for path in paths:
        dataset = load_dataset(path)
        x_s, x_t = dataset.model_inputs()
        keep = np.ones(len(x_s), bool)
        if first_episodes is not None:
            keep = dataset.episode < first_episodes
        pairings: list[tuple[str, np.ndarray | None]] = [("", None)]
        if repair:
            pairings += [(how, repaired_source_rows(dataset, how, seed)) for how in REPAIRINGS]
        for how, source_rows in pairings:
            x_paired = x_s if source_rows is None else x_s[source_rows]
            r2 = pairing_r2(x_paired[keep], x_t[keep], dataset.episode[keep], rows, seed)
            alignment = str(dataset.header.get("alignment")) + (
                f", re-paired: {how}" if how else ""
            )
            r2_rows.append(
                f"| {path} | {alignment} | {int(keep.sum())} | "
                f"{r2['source_to_target']:.3f} | {r2['target_to_source']:.3f} | "
                f"{r2['source_to_shuffled_target']:.3f} |"
            )
        if model is not None:
            info = code_information(model, x_s[keep], x_t[keep], code_rows_wanted, seed, bank)
            code_rows.append(_code_row(str(path), str(model_path), info))
    # returned once every input has been read, so a bad one leaves no half table
    lines = [
        "| dataset | alignment | rows | R² source → target | target → source | shuffled |",
        "|---|---|---|---|---|---|",
        *r2_rows,
    ]
    if code_rows:
        lines += ["", CODE_HEADER.format(what="dataset"), *code_rows]
    return "\n".join(lines)


CODE_HEADER = (
    "| {what} | model | KL(c ‖ prior), source encoder | target encoder "
    "| D matched: median / mean | D shuffled: median / mean "
    "| KL(c ‖ prior), source bank on the target task | D bank vs target: median / mean |\n"
    "|---|---|---|---|---|---|---|---|"
)


def _nats(value: float | None) -> str:
    return "–" if value is None else f"{value:.3g}"


def _code_row(where: str, name: str, info: dict[str, Any]) -> str:
    """One row of :data:`CODE_HEADER`'s table from :func:`code_information`'s result."""
    m, s, on_bank = info["matched"], info["shuffled"], info.get("bank_vs_target")
    bank_d = "–" if on_bank is None else f"{on_bank['q50']:.3g} / {on_bank['mean']:.3g}"
    return (
        f"| {where} | {name} | {_nats(info['kl_prior_source'])} | "
        f"{_nats(info['kl_prior_target'])} | {m['q50']:.3g} / {m['mean']:.3g} | "
        f"{s['q50']:.3g} / {s['mean']:.3g} | {_nats(info.get('kl_prior_bank'))} | {bank_d} |"
    )


def protocol_pairing_signal(
    protocol: Path,
    rows: int = 100_000,
    code_rows: int = 20_000,
    alpha3: Sequence[float] = (),
    seed: int = 0,
) -> tuple[dict[str, Any], str]:
    """Both measures of the module docstring for every pair of the finished protocol
    directory ``protocol``: the pairing's R² on ``rows`` paired rows, and the codes of each
    selected model (and of PVED refitted at each ``alpha3``) on ``code_rows`` rows.

    Writes ``protocol/subspaces/pairing_signal.json`` and returns its content with the
    tables as Markdown; a directory that is no finished protocol, or lacks the paired
    dataset or a selected model, raises :class:`PvedError`."""
    summary = load_summary(protocol)
    runs_root = protocol / "runs"
    result: dict[str, Any] = {"rows": rows, "code_rows": code_rows, "pairs": {}}
    pairing_rows, code_table = [], []
    for pair, entry in summary["pairs"].items():
        layout = resolve_pair(pair, runs_root)
        dataset_path = layout.runs.dataset(layout.preset.pairing.align)
        if not dataset_path.is_file():
            raise PvedError(f"{dataset_path}: the pair's paired dataset is not in this directory")
        dataset = load_dataset(dataset_path)
        x_s, x_t = dataset.model_inputs()
        r2 = pairing_r2(x_s, x_t, dataset.episode, rows, seed)
        pair_result: dict[str, Any] = {"pairing_r2": r2, "models": {}}
        pairing_rows.append(
            f"| {pair} | {r2['source_to_target']:.3f} | {r2['target_to_source']:.3f} | "
            f"{r2['source_to_shuffled_target']:.3f} |"
        )
        models: dict[str, SharedSpaceModel] = {}
        for method, state in entry["methods"].items():
            init = state.get("init")
            if init is None:  # plain PPO and the oracle have no model
                continue
            path = layout.runs.model(method, init)
            if not path.is_file():
                raise PvedError(f"{path}: the selected model is not in this directory")
            models[f"{method} (init {init})"] = load_model(path).eval()
        pved_name = f"pved (init {entry['methods'].get('pved', {}).get('init')})"
        for weight in alpha3:
            if pved_name not in models:
                raise PvedError(f"{protocol}: no selected pved model on {pair} to refit")
            selected_pved = models[pved_name]
            out = protocol / "subspaces" / "pairing_signal" / pair / f"pved-alpha3-{weight:g}"
            models[f"{pved_name}, α3 = {weight:g}"] = refit_alpha3(
                selected_pved, x_s, x_t, dataset.state_dims, weight, out / "model.pt"
            )
        preset = get_preset(pair)
        bank_name = f"{preset.source_agent}-{preset.target_task}"
        bank_path = run_path(runs_root, pair, "bank", bank_name, 0) / "bank.npz"
        bank = bank_rows(bank_path).astype(np.float32) if bank_path.is_file() else None
        for name, model in models.items():
            info = code_information(model, x_s, x_t, code_rows, seed, bank)
            pair_result["models"][name] = info
            code_table.append(_code_row(pair, name, info))
        result["pairs"][pair] = pair_result
    lines = [
        "| pair | R² source → target | target → source | source → shuffled target |",
        "|---|---|---|---|",
        *pairing_rows,
        "",
        CODE_HEADER.format(what="pair"),
        *code_table,
    ]
    out_json = protocol / "subspaces" / "pairing_signal.json"
    out_json.parent.mkdir(exist_ok=True)
    atomic_write_json(out_json, result)
    return result, "\n".join(lines)


#: How the held-out R² (source → target, less the shuffled floor) is read: at or above
#: the first "strongly", above the second "weakly", else "not" (a reading, not a test; the
#: built-in pairs sit at 0.70-0.72 and 0.09-0.14).
STRONG_R2, WEAK_R2 = 0.5, 0.05


def pair_signal(
    pair: str,
    *,
    episodes: int = 100,
    rows: int = 20_000,
    seed: int = 0,
    runs_root: Path | None = None,
) -> dict[str, Any]:
    """Collect ``episodes`` paired episodes of ``pair`` (a built-in name or a spec file),
    into ``runs_root`` if given (kept, and reused when run again) or a temporary folder,
    and return ``{"pair", "episodes", "rows", "alignment", "r2": {"source_to_target",
    "target_to_source", "source_to_shuffled_target"}, "reading"}``. The options are
    checked before anything is collected."""
    check_int("--episodes", episodes, low=HELD_OUT_MIN_EPISODES)
    check_int("--rows", rows, low=100)
    check_seed("--seed", seed)
    preset = get_preset(pair)
    with tempfile.TemporaryDirectory(prefix="pved-signal-") as tmp:
        root = Path(tmp) if runs_root is None else Path(runs_root)
        path = collect_pairs(pair, episodes=episodes, seed=seed, runs_root=root, progress=False)
        dataset = load_dataset(path)
    x_s, x_t = dataset.model_inputs()
    r2 = pairing_r2(x_s, x_t, dataset.episode, rows, seed)
    gain = r2["source_to_target"] - r2["source_to_shuffled_target"]
    level = "strongly" if gain >= STRONG_R2 else "weakly" if gain > WEAK_R2 else "not"
    reading = f"the pairing relates the agents {level} (R² {gain:.2f} above the shuffled floor)"
    if level == "not":
        reading += ": a model of these pairs has nothing to share, and Eq. 10 nothing to steer by"
    return {
        "pair": preset.name,
        "episodes": episodes,
        "rows": int(min(rows, len(x_s))),
        "alignment": str(dataset.header.get("alignment")),
        "r2": r2,
        "reading": reading,
    }


#: The regression holds out every tenth episode: with fewer than 20, too few are held out.
HELD_OUT_MIN_EPISODES = 20


def format_signal(result: dict[str, Any]) -> str:
    """The result of :func:`pair_signal` as a Markdown table and its reading."""
    r2 = result["r2"]
    return "\n".join(
        [
            f"{result['pair']}: {result['episodes']} paired episodes "
            f"({result['alignment']} alignment), {result['rows']:,} rows, held-out ridge R²",
            "",
            "| source → target | target → source | source → shuffled target |",
            "|---|---|---|",
            f"| {r2['source_to_target']:.3f} | {r2['target_to_source']:.3f} "
            f"| {r2['source_to_shuffled_target']:.3f} |",
            "",
            result["reading"][0].upper() + result["reading"][1:] + ".",
        ]
    )
