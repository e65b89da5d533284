"""``pved <verb>``: thin command-line layer over :mod:`pved.experiments.stages`.

Every verb calls the Python function of the same name with the same arguments; its
handler and parser live in :mod:`pved.commands`, beside the other verbs of its kind. Bad
input (an unknown name, mismatched dims, a corrupt file, NaN in training) prints one
line ``pved: error: ...`` and exits with status 2; results are only ever written
atomically, so nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from functools import partial


def _resolve_pairs(args: argparse.Namespace) -> None:
    """A ``--pair`` given as a spec file is read here, before any work, and stands for its
    name from then on: every stage looks pairs up by name (:func:`pved.spec.load_pair`
    remembers the spec) and keeps their runs under it."""
    from pved.spec import load_pair

    pair = getattr(args, "pair", None)
    if isinstance(pair, str):
        args.pair = load_pair(pair).name
    elif isinstance(pair, list):
        args.pair = [load_pair(p).name for p in pair]


def build_parser() -> argparse.ArgumentParser:
    """The ``pved`` argument parser (sub-commands)."""
    # the names a choice takes, from the registries that check them (each checks its own
    # and names the known ones in a one-line error, so argparse's `choices` is not used)
    from pved.commands import Parser, Verbs, analysis, protocol, runs_parser, stages
    from pved.models import MODELS
    from pved.spec import PRESETS
    from pved.transfer.methods import METHODS

    pairs = " | ".join(sorted(PRESETS))
    models = " | ".join(sorted(MODELS))
    methods = " | ".join(sorted(METHODS))
    pair_help = f"{pairs}, or a pair spec file (.toml; docs/pairs.md) (default: %(default)s)"
    pair_tasks = "; ".join(
        f"{name}: {preset.training_task} | {preset.target_task}"
        for name, preset in sorted(PRESETS.items())
    )

    from pved.rl.ppo import CHECKPOINT_SECONDS

    parser: argparse.ArgumentParser = Parser(
        prog="pved",
        description=__doc__.splitlines()[0],
        epilog="Your own robots: write a pair spec file and give it as --pair SPEC.toml "
        "(docs/pairs.md, 'Bring your own pair'; pved pair show reacher prints one).",
    )
    sub = parser.add_subparsers(dest="verb", required=True)

    def add_checkpoint_seconds(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--checkpoint-seconds",
            type=float,
            default=CHECKPOINT_SECONDS,
            metavar="S",
            help="also checkpoint after the update that ends S seconds of wall time after the "
            "last checkpoint, so that a kill loses at most about that much (0: every update; "
            "inf: only every checkpoint_every env steps; default: %(default)g)",
        )

    verbs = Verbs(
        sub,
        partial(runs_parser, sub),
        add_checkpoint_seconds,
        pairs,
        models,
        methods,
        pair_help,
        pair_tasks,
    )
    for add_verb in (*stages.VERBS, *protocol.VERBS, *analysis.VERBS):
        add_verb(verbs)
    return parser


def protocol_status(argv: Sequence[str]) -> int:
    """``pved protocol status DIR``: parsed and answered before the main parser is built,
    which imports torch (seconds), and beside ``pved protocol``'s own options, which a
    sub-command would clash with (:mod:`pved.protocol.watch`)."""
    from pved.commands import status_parser
    from pved.errors import PvedError
    from pved.protocol.watch import status_text

    try:
        print(status_text(status_parser().parse_args(argv).dir))
    except PvedError as exc:
        print(f"pved: error: {exc}", file=sys.stderr)
        return 2
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pved`` console script."""
    words = list(sys.argv[1:] if argv is None else argv)
    if words[:2] == ["protocol", "status"]:
        return protocol_status(words[2:])
    if words[:1] == ["protocol-status"]:
        return protocol_status(words[1:])
    import torch

    from pved.errors import PvedError

    torch.set_num_threads(1)
    try:
        args = build_parser().parse_args(argv)
        _resolve_pairs(args)
        args.func(args)
    except PvedError as exc:
        print(f"pved: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pved: interrupted (completed stages and checkpoints are kept)", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
