"""`pved report --pair PAIR DIR...`: one self-contained HTML report from other verbs' outputs.

The inputs are built without training: real PNGs drawn with matplotlib, a real GIF written
with imageio, and JSON files in the schemas their writers use (protocol.summarize,
analysis.report.transfer_report, tsne.subspace_numbers, bound.BoundResult).
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pved.cli import main
from pved.diagnostics.bound import estimate_bound
from pved.diagnostics.pair_report import build_pair_report
from pved.errors import PvedError

PVED = [sys.executable, "-m", "pved.cli"]
DATA_IMG = re.compile(r'<img src="data:image/(png|gif);base64,[A-Za-z0-9+/=]+"')


# ------------------------------------------------------------------------------ inputs
def _png(path: Path, label: str) -> Path:
    """A small real PNG (a line plot), so that a browser has something to decode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(2.0, 1.5))
    ax.plot([0, 1, 2], [0.0, 0.5, 0.4])
    ax.set_title(label, fontsize=6)
    fig.savefig(path, format="png", dpi=40)
    plt.close(fig)
    return path


def _gif(path: Path) -> Path:
    import imageio.v3 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    frames = np.zeros((3, 12, 12, 3), dtype=np.uint8)
    for i in range(3):
        frames[i, :, : 4 * (i + 1)] = (255, 80 * i, 0)  # a growing bar, one per frame
    iio.imwrite(path, frames, extension=".gif")
    return path


def _json(path: Path, obj: Any) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2))
    return path


def _protocol_dir(root: Path, pair: str = "reacher") -> Path:
    """A protocol directory as `pved protocol` leaves it (plan, summary, curves)."""
    d = root / f"proto-{pair}"
    _json(
        d / "protocol.json",
        {
            "pairs": [pair],
            "methods": ["pved", "ppo"],
            "budget": {"name": "smoke", "tuning_seeds": [2000, 4000]},
            "transfer_steps": {pair: 8192},
            "beta_grids": {pair: {"pved": [0.1, 0.01]}},
            "pved_version": "0.1.0",
        },
    )

    def method(mean: float, lo: float, hi: float, iqm: float, **extra: Any) -> dict[str, Any]:
        final = {"runs": 2, "mean": mean, "iqm": iqm, "mean_ci": [lo, hi], "iqm_ci": [lo, hi]}
        return {
            "runs_planned": 2,
            "runs_finished": 2,
            "missing": [],
            "final": final,
            "runs": [],
            "curve_steps": [0, 4096, 8192],
            "curve_mean": [0.0, mean / 2, mean],
            "ppo_final": 0.25,
            **extra,
        }

    summary = {
        "pved_version": "0.1.0",
        "budget": "smoke",
        "pairs": {
            pair: {
                "metric": "success_rate",
                "methods": {
                    "pved": method(0.7125, 0.6011, 0.8204, 0.7333, beta=0.01, init=1,
                                   steps_to_ppo_final=4096),
                    "ppo": method(0.25, 0.125, 0.375, 0.25, steps_to_ppo_final=8192),
                },
            }
        },
        "selection": {},
        "failed": {},
        "blocked": [],
        "reused": 0,
        "wall_s": 12.5,
    }  # fmt: skip
    _json(d / "summary.json", summary)
    _json(d / "selection.json", {})
    _png(d / f"curves-{pair}.png", "protocol curves")
    return d


def _transfer_report_dir(root: Path, pair: str = "reacher") -> Path:
    """A runs-mode `pved report` folder (results.json as transfer_report writes it)."""
    d = root / f"transfer-{pair}"
    row = {
        "method": "pved",
        "seeds": [20000, 40000],
        "final_success_rate": [0.9, 0.35],
        "final_mean": 0.625,
        "final_ci95": [0.35, 0.9],
        "final_iqm": 0.6251,
        "final_iqm_ci95": [0.35, 0.9],
        "curve_mean": 0.4321,
        "curve_ci95": [0.3012, 0.5633],
        "final_return_mean": -8.318,
        "final_return_ci95": [-9.5, -7.25],
        "steps": 300000,
    }
    _json(
        d / "results.json",
        {
            "pair": pair,
            "metric": "success_rate",
            "ci95": "[lo, hi], 95% percentile bootstrap over seeds (rliable, 2000 reps, seed 0)",
            "rows": [row],
        },
    )
    _png(d / "curves_success_rate.png", "success")
    _png(d / "curves_return.png", "return")
    return d


NUMBERS = {
    "num_points": {"source": 300, "target": 280},
    "episodes": 6,
    "success_rate": {"source": 1.0, "target": 0.8333},
    "chance_time_difference": 0.3337,
    "shared": {"dim": 6, "nn_time_difference": 0.0712, "agent_probe_accuracy": 0.5143},
    "individual": {"dim": 4, "nn_time_difference": 0.2871, "agent_probe_accuracy": 0.9968},
}


def _tsne_dir(root: Path) -> Path:
    d = root / "tsne"
    for name in ("tsne_shared", "tsne_individual", "mark_1", "mark_2"):
        _png(d / f"{name}.png", name)
    _json(d / "numbers.json", NUMBERS)
    return d


def _bound_result() -> Any:
    """A real BoundResult from estimate_bound on made-up rewards and KLs."""
    rng = np.random.default_rng(0)
    r_s = [rng.uniform(-1.0, 0.0, 20) for _ in range(2)]
    r_t = [r + rng.normal(0.0, 0.05, 20) for r in r_s]
    kl = rng.uniform(0.0, 0.2, 40)
    return estimate_bound(kl, np.concatenate(r_s), np.concatenate(r_t), r_s, r_t)


def _inputs(root: Path) -> list[Path]:
    """Every kind of input; the videos sit one level down to check the recursive search."""
    result = _bound_result()
    (root / "bound.txt").write_text(result.summary() + "\n")  # what `pved bound` prints
    _gif(root / "videos" / "push" / "side_by_side.gif")
    return [
        _protocol_dir(root),
        _transfer_report_dir(root),
        _tsne_dir(root),
        root / "bound.txt",
        root / "videos",
    ]


def _one_line(err: pytest.ExceptionInfo[PvedError]) -> str:
    message = str(err.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------- tests
def test_report_embeds_every_image_and_the_numbers(tmp_path: Path) -> None:
    out = build_pair_report("reacher", _inputs(tmp_path), tmp_path / "out" / "r.html")
    page = out.read_text()
    # 3 curves (protocol 1, transfer report 2) + 4 t-SNE figures + 1 GIF, all data URIs
    assert len(DATA_IMG.findall(page)) == page.count("<img") == 8
    assert len(re.findall(r'<img src="data:image/gif;', page)) == 1
    # nothing is fetched from elsewhere
    assert not re.search(r'(src|href)="(?!data:)', page)
    assert "Reacher3 → Reacher4" in page and "Push" in page
    assert "Not given" not in page
    # sections in order
    heads = re.findall(r"<h2>([^<]+)</h2>", page)
    first_words = ["Learning", "Results", "t-SNE", "Time", "Theorem", "Videos"]
    assert [h.split()[0] for h in heads] == first_words
    # protocol: mean and IQM with CIs, β; transfer report: bootstrap CI, IQM, per seed
    for text in ("0.713 [0.601, 0.820]", "0.733 [0.601, 0.820]", "4,096", '<td class="num">0.01<'):
        assert text in page, text
    for text in (
        "0.625 [0.350, 0.900]",
        "0.90 0.35",
        "0.432 [0.301, 0.563]",
        "-8.32 [-9.50, -7.25]",
    ):
        assert text in page, text
    # the correspondence and probe numbers, each with its explanation
    for text in ("0.071", "0.287", "0.334", "0.514", "0.997", "balanced accuracy"):
        assert text in page, text
    # the bound, from the line `pved bound` prints
    b = _bound_result()
    for value in (b.delta, b.a, b.b, b.m, b.bound, b.gap):
        assert f"{value:.4g}" in page
    assert ('<td class="num">yes</td>' if b.held else '<td class="num">no</td>') in page


def test_bound_json_and_printed_line_agree(tmp_path: Path) -> None:
    """The bound from a JSON of transferred.bound's result and from the printed line."""
    b = _bound_result()
    _json(tmp_path / "j" / "bound.json", {"summary": b.summary(), **b.as_dict()})
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "bound.txt").write_text("some log line\n" + b.summary() + "\n")
    pages = [
        build_pair_report("reacher", [tmp_path / d], tmp_path / f"{d}.html").read_text()
        for d in ("j", "t")
    ]
    cells = [re.findall(r"<td[^>]*>([^<]*)</td>", p) for p in pages]
    assert cells[0] == cells[1] and f"{b.bound:.4g}" in cells[0]
    # only the bound was given: the other sections are named as missing
    assert "Not given: learning curves" in pages[0] and "videos" in pages[0]


def test_old_transfer_report_half_widths(tmp_path: Path) -> None:
    """Reports written before the bootstrap hold ±half-widths (reports/reacher-1m)."""
    d = tmp_path / "old"
    row = {"method": "ppo", "seeds": [1, 2], "final_success_rate": [0.2, 0.0],
           "final_mean": 0.1, "final_ci95": 0.55, "curve_mean": 0.05, "curve_ci95": 0.3,
           "final_return_mean": -11.1, "final_return_ci95": 5.2, "steps": 1000}  # fmt: skip
    _json(d / "results.json", {"pair": "reacher", "metric": "success_rate", "rows": [row]})
    page = build_pair_report("reacher", [d], tmp_path / "r.html").read_text()
    assert "0.100 ± 0.550" in page and "IQM" not in page


def test_video_element_for_mp4(tmp_path: Path) -> None:
    """MP4/WebM go into <video controls> (structure only: the bytes carry just the MP4
    signature; a real clip is checked below where imageio can write one)."""
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"\x00\x00\x00\x18ftypisom" + bytes(16))
    page = build_pair_report("reacher", [clip], tmp_path / "r.html").read_text()
    assert '<video controls preload="metadata" src="data:video/mp4;base64,' in page


def test_real_mp4(tmp_path: Path) -> None:
    if importlib.util.find_spec("imageio_ffmpeg") is None:
        pytest.skip("imageio-ffmpeg is not installed, imageio cannot write MP4 here")
    import imageio.v3 as iio

    clip = tmp_path / "v" / "clip.mp4"
    clip.parent.mkdir()
    iio.imwrite(clip, np.zeros((4, 16, 16, 3), dtype=np.uint8), extension=".mp4", fps=4)
    page = build_pair_report("reacher", [clip.parent], tmp_path / "r.html").read_text()
    assert page.count("data:video/mp4;base64,") == 1


def test_foreign_and_unrecognised_inputs_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "r.html"
    with pytest.raises(PvedError) as err:
        build_pair_report("reacher", [_protocol_dir(tmp_path, "walker-hopper")], out)
    assert "protocol.json" in _one_line(err) and "walker-hopper" in str(err.value)
    with pytest.raises(PvedError) as err:
        build_pair_report("reacher", [_transfer_report_dir(tmp_path, "jaco-fetch")], out)
    assert "results.json" in _one_line(err) and "jaco-fetch" in str(err.value)
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("hello")
    with pytest.raises(PvedError) as err:
        build_pair_report("reacher", [stray], out)
    assert re.fullmatch(r".*stray is not a pved output \(expected .*\)", _one_line(err))
    odd = _json(tmp_path / "odd" / "results.json", {"rows": [{"method": "pved",
                "final_success_rate": ["high"]}]})  # fmt: skip
    with pytest.raises(PvedError) as err:
        build_pair_report("reacher", [odd.parent], out)
    assert "odd is not a readable pved output (ValueError" in _one_line(err)
    bad_png = _tsne_dir(tmp_path / "bad")
    (bad_png / "mark_2.png").write_bytes(b"not a png")
    with pytest.raises(PvedError) as err:
        build_pair_report("reacher", [bad_png], out)
    assert "mark_2.png is not a valid PNG" in _one_line(err)
    assert not out.exists()


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, OMP_NUM_THREADS="1", MUJOCO_GL="osmesa")
    cmd = [*PVED, "report", *map(str, args)]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)


def test_cli_refuses_bad_inputs_with_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "r.html"
    stray = tmp_path / "stray"
    stray.mkdir()
    foreign = _protocol_dir(tmp_path, "walker-hopper")
    for bad in (foreign, stray):
        res = _cli("--pair", "reacher", bad, _tsne_dir(tmp_path), "--out", out)
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pved: error: "), res.stderr
        assert str(bad) in lines[0]
        assert not out.exists() and res.stdout == ""
    assert not list(tmp_path.glob(".r.html.*"))  # no temporary file left either


def test_cli_in_process(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The verb's wiring: DIRs give the HTML, no DIRs keep the runs report's options."""
    out = tmp_path / "r.html"
    assert main(["report", "--pair", "reacher", str(_tsne_dir(tmp_path)), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out) and out.is_file()
    assert main(["report", "--pair", "reacher"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pved: error: report needs DIR") and "\n" not in err
    assert main(["report", str(tmp_path / "tsne"), "--seeds", "1"]) == 2
    assert "--seeds and --methods" in capsys.readouterr().err


# ------------------------------------------------------------------- headless browser
def _images_in_browser(page: Path, tmp_path: Path) -> tuple[int, int]:
    """(loaded, total) images of ``page`` after its load event, from headless Chromium."""
    chromium = shutil.which("chromium")
    assert chromium is not None
    profile = tmp_path / f"profile-{page.stem}"
    cmd = [
        chromium,
        "--headless",
        "--no-sandbox",  # Chromium refuses to run as root with its sandbox
        "--disable-gpu",
        "--disable-dev-shm-usage",  # containers have a small /dev/shm
        "--no-first-run",
        f"--user-data-dir={profile}",  # no shared profile, no lock with another run
        "--virtual-time-budget=10000",  # let the load event fire before the DOM is dumped
        "--dump-dom",
        page.resolve().as_uri(),
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr[-2000:]
    body = re.search(r"<body[^>]*>", res.stdout)
    assert body is not None, res.stdout[:500]
    loaded = re.search(r'data-images-loaded="(\d+)"', body.group(0))
    total = re.search(r'data-images-total="(\d+)"', body.group(0))
    assert loaded and total, f"the load script did not run: {body.group(0)}"
    return int(loaded.group(1)), int(total.group(1))


def test_every_image_decodes_in_headless_chromium(tmp_path: Path) -> None:
    if shutil.which("chromium") is None:
        pytest.skip("chromium is not installed (scripts/install-system-deps.sh installs it)")
    page = build_pair_report("reacher", _inputs(tmp_path), tmp_path / "r.html")
    loaded, total = _images_in_browser(page, tmp_path)
    assert loaded == total == 8
    # The check can fail: one PNG's bytes corrupted after its signature.
    html = page.read_text()
    start = html.index("data:image/png;base64,") + len("data:image/png;base64,") + 12
    broken = tmp_path / "broken.html"
    broken.write_text(html[:start] + "A" * 400 + html[start + 400 :])
    loaded, total = _images_in_browser(broken, tmp_path)
    assert total == 8 and loaded == 7


def test_a_bound_line_from_before_delta_was_the_max_is_read_with_the_max(tmp_path: Path) -> None:
    """bound.txt files published before 2026-12-05 took a KL quantile for δ; the report
    reads them with δ = the max KL they print (humanoid-ant's paper protocol)."""
    line = (
        "Theorem 1: delta(q0.95)=8.516 (KL max 172.7), [a,b]=[-1.03,7.139], m=6.793 -> "
        "bound 23.65 vs gap 4.232 (held); Corollary 1 (gamma=0.99): bound 2365 (finite "
        "n=1000: 2365) vs return gap 469.7 (held)"
    )
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "bound.txt").write_text(line + "\n")
    page = build_pair_report("humanoid-ant", [tmp_path / "old"], tmp_path / "r.html").read_text()
    bound = 6.793 + (7.139 + 1.03) / 2 * math.sqrt(2 * 172.7)
    assert f"{bound:.4g}" in page and f"{172.7:.4g}" in page
    assert "vacuous" in page and '<td class="num">yes</td>' in page
    # the quantile's right-hand side is shown, named as what it is
    assert "23.65" in page and "not a bound" in page
