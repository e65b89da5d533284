"""The ``pved`` verbs, grouped by what they run: the pipeline's stages
(:mod:`pved.commands.stages`), the protocol (:mod:`pved.commands.protocol`) and the
analyses (:mod:`pved.commands.analysis`). Each verb is a handler and, beside it, the
function that adds its parser; :func:`pved.cli.build_parser` calls those in order.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn


class Parser(argparse.ArgumentParser):
    """argparse, with its refusals (a value of the wrong type, a missing or unknown
    option) as one ``pved: error:`` line and exit status 2, like every other refusal,
    rather than the usage text and a second line."""

    def error(self, message: str) -> NoReturn:
        from pved.errors import PvedError

        raise PvedError(f"{message} (see: {self.prog} --help)")


def runs_parser(
    sub: Any, name: str, help_text: str, runs_default: str = "runs"
) -> argparse.ArgumentParser:
    """A verb's parser with ``--runs``, the root of the run directories it reads or writes."""
    p: argparse.ArgumentParser = sub.add_parser(name, help=help_text, description=help_text)
    p.add_argument(
        "--runs",
        type=Path,
        default=Path(runs_default),
        help="root of the run directories (default: %(default)s)",
    )
    return p


def status_parser() -> argparse.ArgumentParser:
    """The parser of ``pved protocol status DIR`` (alias ``pved protocol-status DIR``)."""
    p = Parser(
        prog="pved protocol status",
        description="a running (or stopped) protocol's progress, read from its directory "
        "alone: runs done, running, failed and left, env steps per second, ETA",
    )
    p.add_argument("dir", type=Path, metavar="DIR", help="the protocol's --out directory")
    return p


@dataclass(frozen=True)
class Verbs:
    """What every verb's parser function is handed.

    Attributes:
        sub: the sub-command parsers (``sub.add_parser``).
        add: a verb's parser with ``--runs``: :func:`runs_parser` with ``sub`` given.
        add_checkpoint_seconds: adds ``--checkpoint-seconds`` to a parser.
        pairs, models, methods: the names a ``--pair``, ``--model`` or transfer method
            takes, for help texts (from the registries that check them).
        pair_help: the help of ``--pair``; pair_tasks: each built-in pair's two tasks.
    """

    sub: Any  # argparse's _SubParsersAction, whose type is private
    add: Callable[..., argparse.ArgumentParser]
    add_checkpoint_seconds: Callable[[argparse.ArgumentParser], None]
    pairs: str
    models: str
    methods: str
    pair_help: str
    pair_tasks: str


def print_json(obj: Any) -> None:
    """Print ``obj`` as indented JSON (numpy values and paths made JSON-able)."""
    from pved.runs import to_jsonable

    print(json.dumps(to_jsonable(obj), indent=2))
