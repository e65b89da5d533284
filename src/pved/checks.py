"""Checks of the values a user gives, made before any work starts (docs/decisions.md,
"Bad input and kills").

Every verb's function takes its options as arguments; each value lands in a config
(:class:`pved.rl.ppo.PPOConfig`, :class:`pved.config.TransferConfig`, ...) whose
``__post_init__`` checks it with the functions below, naming its field. The function that
fills a config from its arguments wraps that in :func:`named_options`, so that the one
line the user reads names the option as they gave it (``--steps``, not ``total_steps``).
A value no config holds (a seed of ``pved evaluate``, an output path) is checked where
the function receives it, with the same functions.

Each check refuses a wrong type as it refuses a value out of range: ``"3"``, ``True`` and
``2.5`` are no count of episodes.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pved.errors import OptionError, PvedError

#: Seeds go to numpy's and gymnasium's generators, which take no negative number, and
#: to torch's, which takes at most 64 bits: a seed is an unsigned 32-bit integer.
SEED_MAX = 2**32 - 1


def check_int(
    option: str, value: object, *, low: int | None = None, high: int | None = None
) -> int:
    """``value`` as an int when it is an integer (not a bool) in ``[low, high]``; else
    :class:`OptionError` naming ``option``."""
    rule = "an integer" + (f" >= {low}" if low is not None else "")
    if high is not None:
        rule = f"an integer in [{low}, {high}]" if low is not None else f"an integer <= {high}"
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise OptionError(option, value, rule)
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        raise OptionError(option, value, rule)
    return number


def check_seed(option: str, value: object) -> int:
    """A seed: an integer in ``[0, SEED_MAX]``."""
    return check_int(option, value, low=0, high=SEED_MAX)


def check_number(
    option: str,
    value: object,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    infinite: bool = False,
) -> float:
    """``value`` as a float when it is a real number (not a bool) within the bounds
    (``low_open``/``high_open``: the bound itself excluded); NaN never, ±inf only with
    ``infinite``. Else :class:`OptionError` naming ``option``."""
    parts = []
    if low is not None:
        parts.append(f"{'>' if low_open else '>='} {low:g}")
    if high is not None:
        parts.append(f"{'<' if high_open else '<='} {high:g}")
    rule = ("a number" if infinite else "a finite number") + (
        " " + " and ".join(parts) if parts else ""
    )
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise OptionError(option, value, rule)
    number = float(value)
    if math.isnan(number) or (math.isinf(number) and not infinite):
        raise OptionError(option, value, rule)
    if low is not None and (number < low or (low_open and number == low)):
        raise OptionError(option, value, rule)
    if high is not None and (number > high or (high_open and number == high)):
        raise OptionError(option, value, rule)
    return number


def check_choice(option: str, value: object, choices: Sequence[str]) -> str:
    """``value`` when it is one of ``choices``; else :class:`OptionError` listing them."""
    if not isinstance(value, str) or value not in choices:
        raise OptionError(option, value, "one of " + ", ".join(choices))
    return value


def given(**values: Any) -> dict[str, Any]:
    """The keyword arguments that were given (not None): a config's fields to replace."""
    return {key: value for key, value in values.items() if value is not None}


@contextmanager
def named_options(**names: str) -> Iterator[None]:
    """Re-raise an :class:`OptionError` about a config field under the option the user
    gave it as: ``with named_options(total_steps="--steps"): PPOConfig(total_steps=s)``."""
    try:
        yield
    except OptionError as err:
        if err.option in names:
            raise err.renamed(names[err.option]) from None
        raise


def check_writable(option: str, path: Path | str, *, directory: bool = True) -> Path:
    """Raise :class:`PvedError` naming ``option`` when ``path`` cannot be written: a
    ``directory`` (to be made where missing) whose nearest existing part is a file or not
    writable, or a file whose directory is so or which is a directory itself. Checked
    before the work that would end in writing it; nothing is created."""
    path = Path(path)
    if not directory and path.is_dir():
        raise PvedError(f"{option} {path} is a directory, not a file")
    if directory and path.exists() and not path.is_dir():
        raise PvedError(f"{option} {path} is a file, not a directory")
    existing = path if directory else path.parent
    # the nearest part of the path that exists is the one whose permissions decide
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise PvedError(f"{option} {path} cannot be made: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PvedError(f"{option} {path} cannot be written: {existing} is not writable")
    return path
