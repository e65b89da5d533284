"""t-SNE analysis of the learned shared and individual subspaces (paper IV.C, Figs. 4–7).

The paper runs the source and the transferred target policy on the target task, embeds
each step's shared factor c and individual factor u of both agents with t-SNE, colours the
points by normalised time (one colour map per agent), and shows the source and target
frames nearest to a few marks spread over the shared embedding. Beside the pictures this
module reports two numbers that make the visual claims checkable:

* cross-agent time correspondence: for each target step, the normalised time of its
  nearest source step in a subspace; a small mean |Δt| in the shared subspace means the
  shared factor aligns the two agents' task stages ("smooth patterns along the
  timesteps", IV.C);
* a linear probe of agent identity: held-out balanced accuracy of a logistic regression.
  The individual subspace should separate the agents (≈1), the shared one should not
  (≈0.5), which is the paper's "distinct and well separated" vs "overlap" reading.

For Humanoid → Ant (Fig. 7 and Fig. 8 of the paper) two additions:

* later frames: the target's strip of a mark can show, below the nearest frame, frames a
  few steps later in the same episode (:func:`later_frame_indices`; the paper shows two
  for Ant "because we find the movement of Ant is not clear with a single frame");
* the x split (Fig. 8): the target's points of the shared embedding are grouped by
  k-means and each group's points counted before and after an x threshold (the Curve's
  12 m, where its slope stops rising), from the torso x the locomotion envs report
  (:func:`x_split_by_group`, :func:`write_x_split`).

The rollouts come from :mod:`pved.diagnostics.rollouts`.

One module past 600 lines on purpose: the embeddings, the two numbers and the figures of
Figs. 4–8 are one analysis of one set of rollouts, each figure drawn from the numbers
above it.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pved.diagnostics.rollouts import EpisodeRecord, make_env, model_inputs, run_paired_episodes
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.rl.policy import Policy
from pved.runs import atomic_write_bytes, atomic_write_json

SOURCE, TARGET = 0, 1
AGENT_NAMES = ("source", "target")


def normalised_time(length: int) -> np.ndarray:
    """Step indices scaled to [0, 1] (the colour axis of Figs. 4–7 (c))."""
    if length <= 1:
        return np.zeros(length)
    return np.arange(length) / (length - 1)


# ---------------------------------------------------------------- subspace data
@dataclass
class SubspaceData:
    """Per-step posterior means of both agents on the target task.

    Rows are all source steps (episode by episode) followed by all target steps.

    Attributes:
        shared: (N, K) shared posterior means (c_T from q_φS for the source, c_S from
            q_φT for the target, Eq. 7).
        individual: (N, K_I) individual posterior means, or None when the model has no
            individual subspace (or the two agents' ones differ in size).
        agent: (N,) 0 = source, 1 = target.
        episode: (N,) episode index within the agent's rollouts.
        step: (N,) step within the episode.
        time: (N,) normalised time in [0, 1] (step / (episode length − 1)).
        source_episodes / target_episodes: the rollouts, for re-simulating frames.
        source_env_id / target_env_id / source_env_kwargs / target_env_kwargs: the envs.
        x_position: (N,) torso x (m) of each step where the env reports it (NaN for the
            rows of an agent whose env does not), or None when neither env does; the
            x split of Fig. 8 needs it.
    """

    shared: np.ndarray
    individual: np.ndarray | None
    agent: np.ndarray
    episode: np.ndarray
    step: np.ndarray
    time: np.ndarray
    source_episodes: list[EpisodeRecord]
    target_episodes: list[EpisodeRecord]
    source_env_id: str
    target_env_id: str
    source_env_kwargs: dict[str, Any] = field(default_factory=dict)
    target_env_kwargs: dict[str, Any] = field(default_factory=dict)
    x_position: np.ndarray | None = None

    @property
    def num_points(self) -> int:
        return int(self.agent.shape[0])


@torch.no_grad()
def embed_rollouts(
    model: SharedSpaceModel,
    source_policy: Policy,
    target_policy: Policy,
    source_env_id: str,
    target_env_id: str,
    episodes: int,
    seed: int,
    *,
    match_keys: Sequence[str] = (),
    source_env_kwargs: Mapping[str, Any] | None = None,
    target_env_kwargs: Mapping[str, Any] | None = None,
    max_steps: int | None = None,
    deterministic: bool = True,
) -> SubspaceData:
    """Run both policies on their target-task envs and encode every step (paper IV.C:
    "we run multiple episodes using the learned policies of the source and target agents;
    then, for each subspace, we compute two-dimensional t-SNE embeddings").

    Args:
        model: a trained shared-space model (inputs raw ``concat(robot_state, action)``).
        source_policy / target_policy: the source's target-task policy and the
            transferred target policy.
        source_env_id / target_env_id: e.g. ``pved/Reacher3Push-v0``, ``pved/Reacher4Push-v0``.
        episodes: episodes per agent; episode ``e`` uses seed ``seed + e`` for both.
        match_keys: task parameters copied from the source's reset to the target's
            (e.g. ``("button_start",)``), so both solve the same instance.
        max_steps: cap on steps per episode (None: the env's own limit).
    """
    src, tgt, idx_s, idx_t = run_paired_episodes(
        source_policy,
        target_policy,
        source_env_id,
        target_env_id,
        episodes,
        seed,
        match_keys=match_keys,
        source_env_kwargs=source_env_kwargs,
        target_env_kwargs=target_env_kwargs,
        max_steps=max_steps,
        deterministic=deterministic,
    )
    if len(idx_s) != model.source_state_dim or len(idx_t) != model.target_state_dim:
        raise PvedError(
            f"the envs' robot states ({len(idx_s)}, {len(idx_t)}) do not match the model's "
            f"({model.source_state_dim}, {model.target_state_dim})"
        )
    model.eval()
    x_s = torch.cat([model_inputs(e, idx_s) for e in src])
    x_t = torch.cat([model_inputs(e, idx_t) for e in tgt])
    shared = torch.cat([model.shared_source(x_s).mean, model.shared_target(x_t).mean])
    ind_s, ind_t = model.individual_source(x_s), model.individual_target(x_t)
    individual: np.ndarray | None = None
    # Both agents' individual factors go into one embedding, so they need one size.
    if ind_s is not None and ind_t is not None and ind_s.mean.shape[1] == ind_t.mean.shape[1]:
        individual = torch.cat([ind_s.mean, ind_t.mean]).double().numpy()
    agent, episode, step, time, x_pos = [], [], [], [], []
    for a, eps in ((SOURCE, src), (TARGET, tgt)):
        for e, ep in enumerate(eps):
            agent.append(np.full(ep.length, a))
            episode.append(np.full(ep.length, e))
            step.append(np.arange(ep.length))
            time.append(normalised_time(ep.length))
            x_pos.append(np.full(ep.length, np.nan) if ep.x_position is None else ep.x_position)
    x_all = np.concatenate(x_pos)
    return SubspaceData(
        shared=shared.double().numpy(),
        individual=individual,
        agent=np.concatenate(agent),
        episode=np.concatenate(episode),
        step=np.concatenate(step),
        time=np.concatenate(time),
        source_episodes=src,
        target_episodes=tgt,
        source_env_id=source_env_id,
        target_env_id=target_env_id,
        source_env_kwargs=dict(source_env_kwargs or {}),
        target_env_kwargs=dict(target_env_kwargs or {}),
        x_position=None if np.all(np.isnan(x_all)) else x_all,
    )


# ------------------------------------------------------------------------ t-SNE
def default_perplexity(num_points: int) -> float:
    """sklearn's default 30, lowered for small point sets: perplexity must stay below the
    number of points, and about N/3 keeps each point's neighbourhood a minority."""
    if num_points < 3:
        raise PvedError(f"t-SNE needs at least 3 points, got {num_points}")
    return float(min(30.0, max(1.0, (num_points - 1) / 3.0)))


def tsne_2d(points: np.ndarray, seed: int = 0, perplexity: float | None = None) -> np.ndarray:
    """Two-dimensional t-SNE embedding (van der Maaten & Hinton 2008) of ``points`` (N, K),
    with a fixed seed and PCA initialisation so reruns give the same picture."""
    from sklearn.manifold import TSNE
    from threadpoolctl import threadpool_limits

    x = np.asarray(points, dtype=np.float64)
    perp = default_perplexity(x.shape[0]) if perplexity is None else float(perplexity)
    tsne = TSNE(n_components=2, perplexity=perp, init="pca", random_state=seed)
    # One thread: with torch's OpenMP runtime loaded, sklearn's Barnes-Hut threads
    # oversubscribe busy cores (100x slower measured); a few thousand points need
    # only seconds on one core.
    with threadpool_limits(limits=1):
        return np.asarray(tsne.fit_transform(x), dtype=np.float64)


def subspace_embeddings(data: SubspaceData, seed: int = 0) -> dict[str, np.ndarray]:
    """``{"shared": (N, 2), "individual": (N, 2)}`` t-SNE embeddings (the latter only when
    the data has an individual subspace), to share one embedding between the scatters,
    the marks and the x split."""
    emb = {"shared": tsne_2d(data.shared, seed)}
    if data.individual is not None:
        emb["individual"] = tsne_2d(data.individual, seed)
    return emb


def mark_positions(embedding: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """``k`` positions spread over a 2-D embedding: k-means centres, which sit in the
    populated regions (a farthest-point pick would favour isolated outliers)."""
    from sklearn.cluster import KMeans

    k = min(k, embedding.shape[0])
    km = KMeans(n_clusters=k, n_init=10, random_state=seed).fit(embedding)
    centres = np.asarray(km.cluster_centers_)
    # Sorted left to right so the numbering (1)..(k) reads in a fixed order.
    return centres[np.argsort(centres[:, 0])]


def _nearest(embedding: np.ndarray, mask: np.ndarray, position: np.ndarray) -> int:
    rows = np.flatnonzero(mask)
    d = np.linalg.norm(embedding[rows] - position, axis=1)
    return int(rows[np.argmin(d)])


# ------------------------------------------------------------ later frames (Fig. 7)
#: Later target frames per mark, by target agent (paper IV.C, Fig. 7 (d)–(h): "we show
#: three frames for Ant: the first frame is the one nearest to the marks ..., the other two
#: frames are two future frames following the first frame. This is because we find the
#: movement of Ant is not clear with a single frame"). Keyed by the target agent rather
#: than the pair because the reason is Ant's body: four alike legs whose pose in one frame
#: does not show which leg is moving. Other agents get none, as in Figs. 4–6.
LATER_FRAMES_BY_TARGET_AGENT: dict[str, int] = {"Ant": 2}

#: Control steps between consecutive later frames. The paper gives no spacing; 5 steps are
#: 0.25 s for Ant (0.05 s per control step), time for a leg to move visibly, while the
#: last of two later frames (0.5 s on) still shows the movement that starts at the nearest
#: frame rather than a later phase of the gait. Consecutive steps (0.05 s) would look alike.
DEFAULT_LATER_FRAME_STRIDE = 5


def default_later_frames(target_agent: str) -> int:
    """Later target frames per mark for ``target_agent`` (2 for Ant, Fig. 7; else 0)."""
    return LATER_FRAMES_BY_TARGET_AGENT.get(target_agent, 0)


def later_frame_indices(t: int, episode_length: int, n: int, stride: int) -> list[int]:
    """Steps of a mark's target strip (Fig. 7 (d)–(h)): the nearest step ``t`` and ``n``
    later steps ``t + stride``, ..., ``t + n·stride`` of the same episode, clamped to its
    last step ``episode_length − 1`` (so a strip near the episode end repeats that step
    rather than leaving the episode).

    Raises:
        PvedError: ``t`` outside the episode, ``n < 0`` or ``stride < 1``.
    """
    if not 0 <= t < episode_length:
        raise PvedError(f"step {t} is outside an episode of {episode_length} steps")
    if n < 0 or stride < 1:
        raise PvedError(f"later frames need n >= 0 and stride >= 1, got n={n}, stride={stride}")
    return [min(t + k * stride, episode_length - 1) for k in range(n + 1)]


@dataclass(frozen=True)
class StripFrame:
    """One frame of a mark strip: ``agent``'s episode ``episode`` before its action
    ``step``; ``offset`` steps after the point nearest the mark (0 for that point), and
    ``clamped`` when the episode ended before the requested offset."""

    agent: int
    episode: int
    step: int
    offset: int
    clamped: bool = False


def mark_strip(
    embedding: np.ndarray,
    data: SubspaceData,
    position: np.ndarray,
    target_later_frames: int = 0,
    later_frame_stride: int = DEFAULT_LATER_FRAME_STRIDE,
) -> list[StripFrame]:
    """The frames of one mark's strip, top to bottom: the source point nearest to
    ``position`` in ``embedding`` (the shared t-SNE embedding, rows as in ``data``), the
    nearest target point, and ``target_later_frames`` later steps of the target's episode
    (:func:`later_frame_indices`; Fig. 7 shows two for Ant)."""
    strip = []
    for a in (SOURCE, TARGET):
        row = _nearest(embedding, data.agent == a, position)
        ep, st = int(data.episode[row]), int(data.step[row])
        strip.append(StripFrame(a, ep, st, 0))
        if a == TARGET and target_later_frames > 0:
            length = int(np.sum((data.agent == a) & (data.episode == ep)))
            steps = later_frame_indices(st, length, target_later_frames, later_frame_stride)
            for k, later in enumerate(steps[1:], start=1):
                strip.append(
                    StripFrame(a, ep, later, later - st, later - st < k * later_frame_stride)
                )
    return strip


def _save_figure(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _scatter(
    embedding: np.ndarray,
    data: SubspaceData,
    title: str,
    path: Path,
    marks: np.ndarray | None = None,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    divider = make_axes_locatable(ax)
    # One colour map per agent so that agent and time can both be read (Figs. 4–7 (c)).
    for a, cmap, marker in ((SOURCE, "viridis", "o"), (TARGET, "autumn", "^")):
        sel = data.agent == a
        sc = ax.scatter(
            embedding[sel, 0],
            embedding[sel, 1],
            c=data.time[sel],
            cmap=cmap,
            vmin=0.0,
            vmax=1.0,
            s=8,
            marker=marker,
            alpha=0.8,
            linewidths=0,
        )
        # Each bar gets its own axes; the second leaves room for the first's labels.
        cax = divider.append_axes("right", size="3%", pad=0.1 if a == SOURCE else 0.75)
        bar = fig.colorbar(sc, cax=cax)
        bar.set_label(f"{AGENT_NAMES[a]} normalised time")
    if marks is not None:
        for j, pos in enumerate(marks, start=1):
            ax.scatter([pos[0]], [pos[1]], marker="x", c="black", s=60)
            ax.annotate(f"({j})", pos, xytext=(4, 4), textcoords="offset points", fontsize=10)
    ax.set_title(title)
    ax.set_xticks([])
    ax.set_yticks([])
    return _save_figure(fig, path)


def replay_frame(env: Any, episode: EpisodeRecord, step: int) -> np.ndarray:
    """The rendered state of ``episode`` before its action ``step``, re-simulated by
    replaying its recorded actions from the same seed and options in ``env`` (a rendering
    Gymnasium-form env of the same id): the rollouts stored no simulator states, and a
    replay is exact because the simulation is deterministic given the seed."""
    return replay_frames(env, episode, [step])[0]


def replay_frames(env: Any, episode: EpisodeRecord, steps: Sequence[int]) -> list[np.ndarray]:
    """:func:`replay_frame` for several ``steps`` of one episode (in the given order,
    repeats allowed) from a single replay, so a strip with later frames costs one."""
    wanted = sorted(set(int(s) for s in steps))
    if wanted and not 0 <= wanted[0] <= wanted[-1] <= episode.length:
        raise PvedError(f"steps {wanted} are outside an episode of {episode.length} steps")
    env.reset(seed=episode.seed, options=episode.options)
    rendered: dict[int, np.ndarray] = {}
    for t in range(wanted[-1] + 1 if wanted else 0):
        if t in wanted:
            rendered[t] = np.asarray(env.render())
        if t < wanted[-1]:
            env.step(episode.act[t])
    return [rendered[int(s)] for s in steps]


def plot_tsne(
    data: SubspaceData,
    out_dir: Path | str,
    marks: int = 4,
    *,
    seed: int = 0,
    image_size: int = 240,
    embeddings: Mapping[str, np.ndarray] | None = None,
    target_later_frames: int = 0,
    later_frame_stride: int = DEFAULT_LATER_FRAME_STRIDE,
) -> list[Path]:
    """Figs. 4–7 (a)–(h): the t-SNE scatter of the shared and (if present) the individual
    subspace, and one PNG strip per mark with the source frame (top) and the target frame
    (below it) nearest to it in the shared embedding, followed by ``target_later_frames``
    later frames of the target's episode (Fig. 7 shows two for Ant).

    Args:
        data: from :func:`embed_rollouts`.
        out_dir: written: ``tsne_shared.png``, ``tsne_individual.png``, ``mark_<j>.png``.
        marks: number of marks on the shared embedding (0: no frames).
        seed: t-SNE and k-means seed.
        image_size: width and height of the rendered frames in pixels.
        embeddings: precomputed ``{"shared": (N, 2), "individual": (N, 2)}``.
        target_later_frames: later target frames per mark (:func:`default_later_frames`).
        later_frame_stride: control steps between them.

    Returns:
        the written paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if target_later_frames < 0 or later_frame_stride < 1:
        raise PvedError(
            f"later frames need target_later_frames >= 0 and later_frame_stride >= 1, got "
            f"{target_later_frames} and {later_frame_stride}"
        )
    out = Path(out_dir)
    emb = dict(embeddings or {})
    if "shared" not in emb:
        emb["shared"] = tsne_2d(data.shared, seed)
    if data.individual is not None and "individual" not in emb:
        emb["individual"] = tsne_2d(data.individual, seed)
    centres = mark_positions(emb["shared"], marks, seed) if marks > 0 else None
    paths = [
        _scatter(emb["shared"], data, "t-SNE, shared subspace", out / "tsne_shared.png", centres)
    ]
    if "individual" in emb:
        paths.append(
            _scatter(
                emb["individual"],
                data,
                "t-SNE, individual subspace",
                out / "tsne_individual.png",
            )
        )
    if centres is None:
        return paths
    envs = [
        make_env(data.source_env_id, data.source_env_kwargs, render=True,
                 width=image_size, height=image_size),
        make_env(data.target_env_id, data.target_env_kwargs, render=True,
                 width=image_size, height=image_size),
    ]  # fmt: skip
    episodes = (data.source_episodes, data.target_episodes)
    try:
        for j, pos in enumerate(centres, start=1):
            strip = mark_strip(emb["shared"], data, pos, target_later_frames, later_frame_stride)
            fig, axes = plt.subplots(
                len(strip), 1, figsize=(3.0, 3.1 * len(strip)), squeeze=False, layout="constrained"
            )
            for a in (SOURCE, TARGET):
                rows = [i for i, f in enumerate(strip) if f.agent == a]
                ep = strip[rows[0]].episode
                frames = replay_frames(envs[a], episodes[a][ep], [strip[i].step for i in rows])
                for i, frame in zip(rows, frames, strict=True):
                    f, ax = strip[i], axes[i, 0]
                    ax.imshow(frame)
                    if f.offset == 0:
                        t = normalised_time(episodes[a][ep].length)[f.step]
                        title = f"{AGENT_NAMES[a]}: ep {ep}, step {f.step}, t={t:.2f}"
                    else:
                        end = " (episode end)" if f.clamped else ""
                        title = f"{AGENT_NAMES[a]}: +{f.offset} steps (step {f.step}){end}"
                    ax.set_title(title, fontsize=8)
                    ax.axis("off")
            fig.suptitle(f"mark ({j})", fontsize=10)
            paths.append(_save_figure(fig, out / f"mark_{j}.png"))
    finally:
        for env in envs:
            env.close()
    return paths


# --------------------------------------------------------------- x split (Fig. 8)
def x_split_by_group(
    embedding: np.ndarray,
    x: np.ndarray,
    threshold: float,
    groups: int = 2,
    seed: int = 0,
    *,
    marks: np.ndarray | None = None,
) -> dict[str, Any]:
    """Fig. 8's statistics: k-means groups of 2-D embedded points, each counted before
    (``x < threshold``) and after (``x >= threshold``) an x position.

    The paper sees Ant's shared embedding fall into two groups (around marks (2) and (4))
    and reads them as two strategies, one for the Curve before 12 m and one for the slope
    after it, "validated by the summary shown in Fig. 8". Each group's fraction after the
    threshold makes that checkable: fractions near 0 and 1 mean the groups are the two
    terrain parts, equal fractions mean the grouping has nothing to do with x.

    Args:
        embedding: (N, 2) points (the target's rows of the shared t-SNE embedding).
        x: (N,) their x positions (m), finite.
        threshold: the x that splits before from after (the Curve's 12 m).
        groups: number of k-means groups (the paper's two).
        seed: k-means seed.
        marks: (k, 2) mark positions in the same embedding; each group then names its
            nearest mark (1-based, as on the scatter), to match groups to marks.

    Returns:
        ``{"threshold_m", "before", "after", "frac_after_range", "groups": [...]}``, groups
        ordered left to right by centre (as the marks are), each ``{"centre": [x, y],
        "size", "before", "after", "frac_before", "frac_after"}`` (+ ``"nearest_mark"``);
        ``frac_after_range`` is the largest minus the smallest ``frac_after`` (1: the
        groups split exactly at the threshold; 0: no relation).
    """
    from sklearn.cluster import KMeans

    emb = np.asarray(embedding, dtype=np.float64)
    xs = np.asarray(x, dtype=np.float64)
    if emb.ndim != 2 or xs.shape != (emb.shape[0],):
        raise PvedError(f"need (N, d) points and (N,) x, got {emb.shape} and {xs.shape}")
    if not np.all(np.isfinite(xs)):
        raise PvedError("x positions must be finite")
    if not 1 <= groups <= emb.shape[0]:
        raise PvedError(f"groups must be in [1, {emb.shape[0]}], got {groups}")
    km = KMeans(n_clusters=groups, n_init=10, random_state=seed).fit(emb)
    order = np.argsort(km.cluster_centers_[:, 0])
    rank = np.empty(groups, dtype=np.int64)
    rank[order] = np.arange(groups)
    labels = rank[km.labels_]
    centres = np.asarray(km.cluster_centers_)[order]
    after = xs >= threshold
    entries: list[dict[str, Any]] = []
    for g, centre in enumerate(centres):
        sel = labels == g
        size, n_after = int(sel.sum()), int(after[sel].sum())
        entry: dict[str, Any] = {
            "centre": [float(v) for v in centre],
            "size": size,
            "before": size - n_after,
            "after": n_after,
            # k-means leaves no group empty; the guard keeps NaN out of the JSON anyway.
            "frac_before": (size - n_after) / size if size else 0.0,
            "frac_after": n_after / size if size else 0.0,
        }
        if marks is not None and len(marks) > 0:
            d = np.linalg.norm(np.asarray(marks, dtype=np.float64) - centre, axis=1)
            entry["nearest_mark"] = int(np.argmin(d)) + 1
        entries.append(entry)
    fracs = [e["frac_after"] for e in entries]
    return {
        "threshold_m": float(threshold),
        "before": int(np.sum(~after)),
        "after": int(np.sum(after)),
        "frac_after_range": float(max(fracs) - min(fracs)),
        "groups": entries,
    }


def plot_x_split(
    embedding: np.ndarray,
    x: np.ndarray,
    split: Mapping[str, Any],
    path: Path | str,
    marks: np.ndarray | None = None,
) -> Path:
    """Fig. 8 as ``path`` (PNG): left, the points in grey shades by group (each point
    joins its nearest centre, the k-means rule) with the group centres and the marks;
    right, per group a bar pair of the points before and after the threshold, with the
    fraction after on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    emb = np.asarray(embedding, dtype=np.float64)
    entries = list(split["groups"])
    centres = np.asarray([e["centre"] for e in entries], dtype=np.float64)
    labels = np.argmin(np.linalg.norm(emb[:, None, :] - centres[None], axis=2), axis=1)
    threshold = float(split["threshold_m"])
    fig, (ax_e, ax_b) = plt.subplots(1, 2, figsize=(10.0, 4.2))
    # Grey shades as the paper's "grayscale groups"; the bars carry the colours.
    shades = np.linspace(0.25, 0.7, len(entries))
    for g, shade in enumerate(shades):
        sel = labels == g
        ax_e.scatter(emb[sel, 0], emb[sel, 1], s=6, color=str(shade), linewidths=0)
        # Below-left of the centre, clear of the marks' labels (above-right of them).
        ax_e.annotate(f"G{g + 1}", centres[g], xytext=(-8, -16), textcoords="offset points",
                      fontsize=11, weight="bold", color="tab:red")  # fmt: skip
    if marks is not None:
        for j, pos in enumerate(np.asarray(marks), start=1):
            ax_e.scatter([pos[0]], [pos[1]], marker="x", c="black", s=60)
            ax_e.annotate(f"({j})", pos, xytext=(4, 4), textcoords="offset points", fontsize=9)
    ax_e.set_title("target points of the shared embedding, by group")
    ax_e.set_xticks([])
    ax_e.set_yticks([])
    pos = np.arange(len(entries))
    width = 0.38
    before = [e["before"] for e in entries]
    after = [e["after"] for e in entries]
    ax_b.bar(pos - width / 2, before, width, color="tab:blue", label=f"x < {threshold:g} m")
    ax_b.bar(pos + width / 2, after, width, color="tab:orange", label=f"x ≥ {threshold:g} m")
    for g, e in enumerate(entries):
        top = max(e["before"], e["after"])
        ax_b.annotate(f"{e['frac_after']:.2f} after", (pos[g], top), ha="center",
                      xytext=(0, 3), textcoords="offset points", fontsize=9)  # fmt: skip
    names = [
        f"G{g + 1}" + (f" (near mark ({e['nearest_mark']}))" if "nearest_mark" in e else "")
        for g, e in enumerate(entries)
    ]
    ax_b.set_xticks(pos, names)
    # Headroom above the tallest bar for the fractions and the legend.
    ax_b.set_ylim(0, 1.25 * max([1, *before, *after]))
    ax_b.set_ylabel("points (steps)")
    ax_b.set_title(f"points before / after x = {threshold:g} m per group")
    ax_b.legend(loc="upper right")
    return _save_figure(fig, Path(path))


def write_x_split(
    data: SubspaceData,
    shared_embedding: np.ndarray,
    out_dir: Path | str,
    threshold: float,
    *,
    groups: int = 2,
    seed: int = 0,
    marks: np.ndarray | None = None,
) -> dict[str, Any] | None:
    """Fig. 8 for the target agent: :func:`x_split_by_group` on the target's rows of
    ``shared_embedding`` (rows as in ``data``) and their x positions, drawn to
    ``out_dir/fig8_groups.png`` (:func:`plot_x_split`).

    Returns:
        the split (with ``"agent": "target"``), or None, writing nothing, when the target's
        env reports no x positions (the arm pairs).
    """
    if data.x_position is None:
        return None
    tgt = data.agent == TARGET
    x = data.x_position[tgt]
    if not np.all(np.isfinite(x)):
        return None
    emb = np.asarray(shared_embedding, dtype=np.float64)[tgt]
    split: dict[str, Any] = {"agent": AGENT_NAMES[TARGET]}
    split.update(x_split_by_group(emb, x, threshold, groups, seed, marks=marks))
    plot_x_split(emb, x, split, Path(out_dir) / "fig8_groups.png", marks)
    return split


# ---------------------------------------------------------------------- numbers
def time_correspondence(features: np.ndarray, agent: np.ndarray, time: np.ndarray) -> float:
    """Mean |t_T − t_S(nn)| over target points, where t_S(nn) is the normalised time of
    the target point's nearest source point (Euclidean, in ``features``)."""
    from scipy.spatial import cKDTree

    src, tgt = agent == SOURCE, agent == TARGET
    if not src.any() or not tgt.any():
        raise PvedError("time correspondence needs points of both agents")
    _, nn = cKDTree(features[src]).query(features[tgt], k=1)
    return float(np.mean(np.abs(time[tgt] - time[src][nn])))


def chance_time_difference(agent: np.ndarray, time: np.ndarray) -> float:
    """Mean |t_T − t_S| over all cross-agent pairs: what an uninformative nearest
    neighbour would give (1/3 for uniform times)."""
    t_s, t_t = time[agent == SOURCE], time[agent == TARGET]
    return float(np.mean(np.abs(t_t[:, None] - t_s[None, :])))


def probe_accuracy(
    features: np.ndarray, labels: np.ndarray, seed: int = 0, test_fraction: float = 0.3
) -> float:
    """Held-out balanced accuracy of a logistic-regression probe predicting ``labels``
    (agent identity) from ``features``: ≈0.5 when the agents are indistinguishable by a
    linear read-out, ≈1 when linearly separable. Balanced, so unequal episode lengths of
    the two agents do not move the chance level off 0.5."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import balanced_accuracy_score
    from sklearn.model_selection import train_test_split
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    x_tr, x_te, y_tr, y_te = train_test_split(
        features, labels, test_size=test_fraction, random_state=seed, stratify=labels
    )
    probe = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))
    probe.fit(x_tr, y_tr)
    return float(balanced_accuracy_score(y_te, probe.predict(x_te)))


def subspace_numbers(data: SubspaceData, seed: int = 0) -> dict[str, Any]:
    """The numbers beside Figs. 4–7, on the posterior means themselves (not the t-SNE
    coordinates, which distort distances): per subspace the cross-agent time
    correspondence and the agent-identity probe accuracy, plus the chance time
    difference and the point counts."""
    result: dict[str, Any] = {
        "num_points": {
            "source": int(np.sum(data.agent == SOURCE)),
            "target": int(np.sum(data.agent == TARGET)),
        },
        "episodes": len(data.source_episodes),
        "success_rate": {
            "source": float(np.mean([e.success for e in data.source_episodes])),
            "target": float(np.mean([e.success for e in data.target_episodes])),
        },
        "chance_time_difference": chance_time_difference(data.agent, data.time),
    }
    spaces = {"shared": data.shared, "individual": data.individual}
    for name, feats in spaces.items():
        if feats is None:
            continue
        result[name] = {
            "dim": int(feats.shape[1]),
            "nn_time_difference": time_correspondence(feats, data.agent, data.time),
            "agent_probe_accuracy": probe_accuracy(feats, data.agent, seed),
        }
    return result


def write_subspace_numbers(data: SubspaceData, out_dir: Path | str, seed: int = 0) -> Path:
    """:func:`subspace_numbers` written atomically to ``out_dir/numbers.json``."""
    path = Path(out_dir) / "numbers.json"
    atomic_write_json(path, subspace_numbers(data, seed))
    return path
