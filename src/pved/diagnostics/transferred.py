"""One transferred target beside its source, on rollouts of the pair's target task.

The two analyses of ``pved tsne`` (paper IV.C, Figs. 4-8) and ``pved bound`` (Theorem 1
and Corollary 1, paper III.E) read the same inputs: a pair's model, the transferred
target policy and the source policy (:func:`analysis_inputs`). They are analyses, not
stages: they write figures and numbers, no run directory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import torch

from pved.checks import check_int, check_number, check_seed, check_writable
from pved.config import PairPreset
from pved.diagnostics.bound import theorem1_bound
from pved.diagnostics.tsne import (
    DEFAULT_LATER_FRAME_STRIDE,
    default_later_frames,
    embed_rollouts,
    mark_positions,
    plot_tsne,
    subspace_embeddings,
    subspace_numbers,
    write_x_split,
)
from pved.envs.terrain import CURVE_RAMP_LENGTH
from pved.models.base import SharedSpaceModel
from pved.models.registry import load_model
from pved.pair import resolve_pair
from pved.rl.policy import Policy, load_policy
from pved.run_layout import check_model_for, policy_path
from pved.runs import atomic_write_json, run_file
from pved.transfer.source_bank import bank_time_scale, env_dt


class AnalysisInputs(NamedTuple):
    """What both analyses read: the pair's preset, its model, both policies and the ids
    of both agents' target-task envs."""

    preset: PairPreset
    model: SharedSpaceModel
    source: Policy
    target: Policy
    source_env_id: str
    target_env_id: str


def analysis_inputs(
    pair: str, model_path: Path | str, target_policy: Path | str, source_policy: Path | str | None
) -> AnalysisInputs:
    """The model at ``model_path`` (refused if made for another pair), the target policy,
    and the source policy (the shipped one for the pair's target task when None)."""
    resolved = resolve_pair(pair)
    preset = resolved.preset
    model = load_model(run_file(model_path, "model.pt"))
    check_model_for(resolved, model, model_path)
    src = load_policy(policy_path(resolved, preset.source_agent, preset.target_task, source_policy))
    tgt = load_policy(run_file(target_policy, "policy.pt"))
    return AnalysisInputs(
        preset,
        model,
        src,
        tgt,
        preset.agent_env(preset.source_agent, preset.target_task).env_id,
        preset.agent_env(preset.target_agent, preset.target_task).env_id,
    )


def analyze_subspaces(
    pair: str,
    model_path: Path | str,
    target_policy: Path | str,
    out: Path | str,
    *,
    source_policy: Path | str | None = None,
    episodes: int = 6,
    marks: int = 4,
    seed: int = 0,
    target_later_frames: int | None = None,
    later_frame_stride: int | None = None,
    x_groups: int = 2,
) -> dict[str, Any]:
    """``pved tsne``: t-SNE of both agents' shared and individual posterior means along
    target-task rollouts (paper IV.C, Figs. 4–7), frames nearest to marks, and the numbers
    beside them (time correspondence, agent-identity probes) in ``out/numbers.json``.

    For Humanoid → Ant also the paper's Fig. 7 and Fig. 8 additions:

    * ``target_later_frames`` later target frames per mark, ``later_frame_stride`` control
      steps apart (None: :func:`pved.diagnostics.tsne.default_later_frames` of the pair's
      target agent, 2 for Ant, and ``DEFAULT_LATER_FRAME_STRIDE``);
    * on Curve, where the envs report the torso x, ``fig8_groups.png`` and
      ``numbers["x_split"]``: the target's shared-embedding points in ``x_groups``
      k-means groups, counted before and after the x where the Curve's slope stops rising
      (``CURVE_RAMP_LENGTH``, 12 m). Other tasks have no such landmark and skip it.
    """
    torch.set_num_threads(1)
    # checked before the rollouts, which take the time, and so is where the figures go
    check_int("--episodes", episodes, low=1)
    check_int("--marks", marks, low=0)
    check_seed("--seed", seed)
    check_int("x_groups", x_groups, low=1)
    if target_later_frames is not None:
        check_int("--later-frames", target_later_frames, low=0)
    if later_frame_stride is not None:
        check_int("--later-frame-stride", later_frame_stride, low=1)
    check_writable("--out", out)
    preset, model, src, tgt, src_id, tgt_id = analysis_inputs(
        pair, model_path, target_policy, source_policy
    )
    # The default follows the target agent (Ant's movement needs several frames, Fig. 7),
    # not the pair's name, so any pair with an Ant target gets it.
    later = (
        default_later_frames(preset.target_agent)
        if target_later_frames is None
        else int(target_later_frames)
    )
    stride = DEFAULT_LATER_FRAME_STRIDE if later_frame_stride is None else int(later_frame_stride)
    data = embed_rollouts(
        model, src, tgt, src_id, tgt_id, episodes, seed, match_keys=preset.bank_match_keys
    )
    out = Path(out)
    # One embedding for the scatters, the marks and the x split, so the groups' centres
    # and the marks are positions in the same picture.
    emb = subspace_embeddings(data, seed)
    figures = plot_tsne(
        data,
        out,
        marks=marks,
        seed=seed,
        embeddings=emb,
        target_later_frames=later,
        later_frame_stride=stride,
    )
    numbers = subspace_numbers(data, seed=seed)
    centres = mark_positions(emb["shared"], marks, seed) if marks > 0 else None
    numbers["marks"] = [] if centres is None else centres.tolist()
    numbers["mark_frames"] = {"target_later_frames": later, "later_frame_stride": stride}
    if preset.target_task == "Curve":
        split = write_x_split(
            data, emb["shared"], out, CURVE_RAMP_LENGTH, groups=x_groups, seed=seed, marks=centres
        )
        if split is not None:
            numbers["x_split"] = split
            figures.append(out / "fig8_groups.png")
    atomic_write_json(out / "numbers.json", numbers)
    return {"figures": [str(p) for p in figures], "numbers": numbers}


def bound(
    pair: str,
    model_path: Path | str,
    target_policy: Path | str,
    *,
    source_policy: Path | str | None = None,
    episodes: int = 10,
    quantile: float = 0.95,
    gamma: float = 0.99,
    seed: int = 0,
) -> dict[str, Any]:
    """``pved bound``: Theorem 1 and Corollary 1 (paper III.E) estimated on rollouts of the
    source and the transferred target, beside the measured gaps."""
    torch.set_num_threads(1)
    check_int("--episodes", episodes, low=1)
    check_number("--quantile", quantile, low=0.0, high=1.0)
    check_number("--gamma", gamma, low=0.0, high=1.0)
    check_seed("--seed", seed)
    preset, model, src, tgt, src_id, tgt_id = analysis_inputs(
        pair, model_path, target_policy, source_policy
    )
    result = theorem1_bound(
        model,
        src,
        tgt,
        src_id,
        tgt_id,
        episodes,
        seed,
        quantile=quantile,
        gamma=gamma,
        match_keys=preset.bank_match_keys,
        time_scale=bank_time_scale(preset.pairing.align, env_dt(src_id), env_dt(tgt_id)),
    )
    return {"summary": result.summary(), **result.as_dict()}
