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
from typing import Any


@dataclass(frozen=True)
class Verbs:
    """What every verb's parser function is handed.

    Attributes:
        sub: the sub-command parsers (``sub.add_parser``).
        add: a verb's parser with ``--runs``: ``add(name, help, runs_default="runs")``.
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
