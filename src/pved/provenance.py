"""What a run's ``config.json`` says of the code and the numbers it ran under, beside
pved's version and commit (:mod:`pved.runs`): whether the source tree differed from that
commit, the numeric stack (Python, numpy, MuJoCo, torch) and the numeric fingerprint.

The fingerprint (docs/decisions/at-scale.md, "The numeric fingerprint") is three digests
of short, fixed computations: a PPO run, a PVED fit, an Eq. 10 shaped run
(:mod:`pved.experiments.fingerprint` computes them). They are pinned in
``fingerprint_pins.json`` beside this module, and ``tests/test_fingerprint.py`` fails
when the code computes other digests, so a commit that changes what a run computes says
so by updating the pin. A run records the id of the pins its code carries: two runs of one
id were made by code that computed the same numbers (a dirty tree aside, which the record
also says). None of this enters a run's config hash: a run is reused, or not, by what it
was asked to compute, not by the code that computed it.

Nothing here imports numpy, torch or MuJoCo: it sits under every layer, like
:mod:`pved.runs`.
"""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from pved.errors import PvedError

#: the pinned digests, one per stage of the fingerprint, and the stack they were pinned under
FINGERPRINT_PINS = Path(__file__).with_name("fingerprint_pins.json")
#: the fingerprint a record made before fingerprints (or under unreadable pins) counts as
UNKNOWN = "unknown"
#: the packages whose arithmetic a run's numbers depend on (their distribution names)
STACK_PACKAGES = ("numpy", "mujoco", "torch")


def fingerprint_id(digests: Mapping[str, str]) -> str:
    """The short id of a set of stage digests (order of the stages does not matter)."""
    text = json.dumps({str(k): str(v) for k, v in digests.items()}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def read_pins(path: Path = FINGERPRINT_PINS) -> dict[str, Any]:
    """The pin file: ``{"digests": {stage: digest}, "pinned_under": {...}}``; PvedError
    (one line, naming the file) when it is missing or not of that form."""
    try:
        pins = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise PvedError(f"{path} is not readable JSON ({type(err).__name__})") from None
    digests = pins.get("digests") if isinstance(pins, dict) else None
    if not isinstance(digests, dict) or not all(isinstance(v, str) for v in digests.values()):
        raise PvedError(f"{path}: no 'digests' of the fingerprint's stages")
    return dict(pins)


def _pinned_id() -> str | None:
    try:
        return fingerprint_id(read_pins()["digests"])
    except PvedError:
        return None


# Read once, when the module loads, as the commit is (pved.runs.git_commit): a long-lived
# process runs the code it imported, whatever the files say later.
_PINNED_AT_IMPORT = _pinned_id()


def pinned_fingerprint() -> str | None:
    """The id of the pins this process's code carries (None without a readable pin file)."""
    return _PINNED_AT_IMPORT


def git_output(*args: str) -> str | None:
    """What ``git ARGS`` prints in the checkout this package lies in, stripped (None
    outside a git checkout, without git, or when git fails): one place for the commit
    (:mod:`pved.runs`) and the dirty flag below."""
    try:
        out = subprocess.run(
            ["git", *args],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _read_git_dirty() -> bool | None:
    """Whether the package's source differs from HEAD: a tracked file changed or a new
    file not ignored (None outside a git checkout, or without git)."""
    status = git_output("status", "--porcelain", "--", ".")
    return None if status is None else bool(status)


_DIRTY_AT_IMPORT = _read_git_dirty()


def git_dirty() -> bool | None:
    """Whether the package's source differed from its commit when this process imported
    pved (None: not a git checkout): a dirty run's commit does not say what it ran."""
    return _DIRTY_AT_IMPORT


def numeric_stack() -> dict[str, str | None]:
    """The versions of Python and of the packages a run's arithmetic comes from (a
    package not installed: None), read from the installed distributions so that MuJoCo
    is not imported for it; and ``torch_cpu``, the SIMD level torch's CPU kernels
    dispatch to on this machine (pved pins OpenBLAS's, MKL's and numpy's, not torch's:
    the same code computes other last digits under AVX-512 than under AVX2)."""
    stack: dict[str, str | None] = {"python": platform.python_version()}
    for name in STACK_PACKAGES:
        try:
            stack[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            stack[name] = None
    try:
        import torch  # when called: importing this module loads neither numpy nor torch
    except ImportError:
        stack["torch_cpu"] = None
    else:
        stack["torch_cpu"] = str(torch.backends.cpu.get_cpu_capability())
    return stack


def record_fields() -> dict[str, Any]:
    """The fields :class:`pved.runs.Run` adds to ``config.json`` beside the commit, never
    to the hashed config: ``git_dirty``, ``stack`` and ``fingerprint``."""
    return {"git_dirty": git_dirty(), "stack": numeric_stack(), "fingerprint": pinned_fingerprint()}


def run_fingerprint(config_record: Mapping[str, Any]) -> str:
    """The fingerprint a run's ``config.json`` records, or :data:`UNKNOWN` (a run made
    before fingerprints). A run resumed under another fingerprint than it started under
    (its ``previous_starts``, :meth:`pved.runs.Run.start`) was made by two codes' arithmetic:
    ``"mixed: A + B"``, which equals no code's, so such a run is not taken for the
    latest start's code (nor copied as made by it)."""

    def one(record: Any) -> str:
        value = record.get("fingerprint") if isinstance(record, Mapping) else None
        return value if isinstance(value, str) and value else UNKNOWN

    earlier = config_record.get("previous_starts")
    starts = [*(earlier if isinstance(earlier, list) else []), config_record]
    seen = list(dict.fromkeys(one(r) for r in starts))
    return seen[0] if len(seen) == 1 else "mixed: " + " + ".join(seen)


def fingerprint_of_run(run_dir: Path) -> str:
    """The fingerprint recorded in ``run_dir/config.json`` (:data:`UNKNOWN` when it
    records none or cannot be read): the analyses read the file, not the run's code."""
    try:
        record = json.loads((Path(run_dir) / "config.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return UNKNOWN
    return run_fingerprint(record) if isinstance(record, dict) else UNKNOWN


def count_fingerprints(fingerprints: list[str]) -> dict[str, int]:
    """How many runs were made under each fingerprint, most runs first (ties by name)."""
    counts: dict[str, int] = {}
    for fp in fingerprints:
        counts[fp] = counts.get(fp, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def fingerprint_mismatch(a: Mapping[str, int], b: Mapping[str, int]) -> str | None:
    """A one-line warning when two groups of runs (their fingerprint counts) were not all
    made under one known fingerprint, else None: their difference may then be the code's
    arithmetic, not the methods'."""
    both = set(a) | set(b)
    if len(both) <= 1 and UNKNOWN not in both:
        return None

    def say(counts: Mapping[str, int]) -> str:
        return ", ".join(f"{fp} ({n})" for fp, n in counts.items()) or "none"

    return f"not made under one known numeric fingerprint: {say(a)} against {say(b)}"
