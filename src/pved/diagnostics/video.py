"""Offscreen videos of policy rollouts (the qualitative counterpart of paper IV.B/IV.C).

GIFs are written with Pillow; ``.mp4`` with imageio and the ffmpeg of imageio-ffmpeg (both
dependencies of pved); the file suffix chooses.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pved.checks import check_int, check_seed, check_writable
from pved.diagnostics.rollouts import make_env, run_episode, shared_task_options
from pved.errors import PvedError
from pved.rl.policy import load_policy
from pved.runs import atomic_write_bytes

VIDEO_SUFFIXES = (".gif", ".mp4")  # the formats _write writes


def _rollout_frames(
    policy_path: Path | str,
    env_id: str,
    seed: int,
    max_steps: int | None,
    width: int,
    height: int,
    env_kwargs: Mapping[str, Any] | None,
    options: Mapping[str, Any] | None,
) -> tuple[list[np.ndarray], dict[str, Any], float]:
    policy = load_policy(policy_path)
    env = make_env(env_id, env_kwargs, render=True, width=width, height=height)
    try:
        frames: list[np.ndarray] = []
        episode = run_episode(env, policy, seed, options, max_steps=max_steps, frames=frames)
        fps = float(env.metadata.get("render_fps", 30))
    finally:
        env.close()
    return frames, episode.reset_info, fps


def _mark_progress(frame: np.ndarray, index: int, total: int) -> np.ndarray:
    """Draw a thin progress bar under the frame. Its last pixel alternates colour every
    frame: GIF writers merge identical consecutive frames (a finished agent holding
    still), and the frame count must stay one per step."""
    out = frame.copy()
    w = out.shape[1]
    filled = max(1, round(w * (index + 1) / max(total, 1)))
    out[-3:, :filled] = (255, 255, 255)
    out[-3:, filled:] = (0, 0, 0)
    out[-1, -1] = (255, 0, 0) if index % 2 else (0, 0, 255)
    return out


def _pad(frames: list[np.ndarray], n: int) -> list[np.ndarray]:
    """Hold the last frame of a shorter episode so both sides run for ``n`` frames."""
    return frames + [frames[-1]] * (n - len(frames))


def _write(frames: list[np.ndarray], out_path: Path, fps: float) -> None:
    if out_path.suffix.lower() == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        buf = io.BytesIO()
        images[0].save(
            buf,
            format="GIF",
            save_all=True,
            append_images=images[1:],
            duration=max(20, round(1000.0 / fps)),  # GIF timing has 10 ms resolution
            loop=0,
        )
        atomic_write_bytes(out_path, buf.getvalue())
    elif out_path.suffix.lower() == ".mp4":
        try:
            import imageio.v3 as iio
        except ImportError:
            raise PvedError("writing .mp4 needs imageio and imageio-ffmpeg; use .gif") from None
        out_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = out_path.with_name(f".{out_path.name}.tmp.mp4")
        iio.imwrite(tmp, np.stack(frames), fps=fps, codec="libx264")
        tmp.replace(out_path)
    else:
        raise PvedError(f"video must end in .gif or .mp4, got {out_path.name!r}")


def render_rollout(
    policy_path: Path | str,
    env_id: str,
    out_path: Path | str,
    seed: int = 0,
    max_steps: int | None = None,
    side_by_side_with: tuple[Path | str, str] | None = None,
    *,
    width: int = 240,
    height: int = 240,
    env_kwargs: Mapping[str, Any] | None = None,
    other_env_kwargs: Mapping[str, Any] | None = None,
    match_keys: Sequence[str] = (),
) -> Path:
    """Render one deterministic episode of a policy offscreen to a GIF (or MP4).

    Args:
        policy_path: the policy file (:func:`pved.rl.policy.load_policy`).
        env_id: its env, e.g. ``pved/Reacher3Push-v0``.
        out_path: ``.gif`` or ``.mp4``.
        seed: reset seed; the second policy (if any) uses the same seed.
        max_steps: cap on the steps (None: the env's limit).
        side_by_side_with: ``(policy_path, env_id)`` of a second policy (e.g. the
            transferred target next to the source), shown to the right.
        match_keys: task parameters copied from the first episode's reset to the second
            (e.g. ``("button_start",)``), so both agents face the same task instance.

    Returns:
        ``out_path``. The video has 1 + (longest episode's steps) frames: the initial
        state and one frame after every step; a shorter episode holds its last frame.
    """
    out = Path(out_path)
    # where the video goes, and what it is, checked before the rendering, which is the work
    if out.suffix.lower() not in VIDEO_SUFFIXES:
        raise PvedError(f"--out must end in .gif or .mp4, got {out.name!r}")
    check_writable("--out", out, directory=False)
    check_seed("--seed", seed)
    if max_steps is not None:
        check_int("--max-steps", max_steps, low=1)
    frames, reset_info, fps = _rollout_frames(
        policy_path, env_id, seed, max_steps, width, height, env_kwargs, None
    )
    if side_by_side_with is not None:
        other_path, other_env = side_by_side_with
        options = shared_task_options(reset_info, match_keys)
        other, _, _ = _rollout_frames(
            other_path, other_env, seed, max_steps, width, height, other_env_kwargs, options
        )
        n = max(len(frames), len(other))
        left, right = _pad(frames, n), _pad(other, n)
        gap = np.full((left[0].shape[0], 4, 3), 255, dtype=np.uint8)  # white separator
        frames = [np.concatenate([lf, gap, rf], axis=1) for lf, rf in zip(left, right, strict=True)]
    frames = [_mark_progress(f, i, len(frames)) for i, f in enumerate(frames)]
    _write(frames, out, fps)
    return out
