"""The protocol's verbs: running it (here or on many machines), keeping it, judging it.

Each verb is a handler (``_cmd_<verb>``: the stage it calls, with the parsed options)
and beside it the function that adds its parser (``add_<verb>``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pved.commands import Verbs, status_parser


def _cmd_protocol(args: argparse.Namespace) -> None:
    from pved.protocol.driver import run_protocol

    summary = run_protocol(
        args.pair,
        budget=args.budget,
        methods=args.methods,
        out=args.out,
        address=args.address,
        workers=args.workers,
        retries=args.retries,
        backend=args.backend,
        stages_from=args.stages_from,
        selection_from=args.selection_from,
        preregistration=args.preregistration or (),
        exploratory=args.exploratory,
        checkpoint_seconds=args.checkpoint_seconds,
    )
    failed = len(summary["failed"]) + len(summary["blocked"])
    print(f"{args.out / 'summary.md'} ({failed} runs failed or blocked)")


def add_protocol(v: Verbs) -> None:
    from pved.config import BUDGETS

    pairs, methods, sub = v.pairs, v.methods, v.sub

    p = sub.add_parser(
        "protocol",
        help="the paper's tuning and evaluation protocol (IV.A) on Ray",
        description="beta and model selection on the tuning seeds, then every evaluation "
        "seed x source policy; curves with bootstrap CIs, summary.json/md. Rerunning the "
        "same command resumes.",
    )
    p.add_argument("--pair", nargs="+", required=True, help=pairs)
    p.add_argument(
        "--budget",
        default="smoke",
        help=f"{' | '.join(BUDGETS)} (paper-45, paper-wide: 45, 81 evaluation runs); "
        "default: %(default)s",
    )
    p.add_argument(
        "--methods", nargs="+", default=["pved", "ppo"], help=f"{methods} (default: pved ppo)"
    )
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--address", help="a running Ray cluster (default: a local one)")
    p.add_argument("--workers", type=int, help="CPUs of the local Ray (default: all)")
    p.add_argument("--retries", type=int, default=2, help="attempts after a run's failure")
    p.add_argument(
        "--backend",
        default="auto",
        help="ray, or processes: a local pool for machines without Ray; default auto: "
        "ray where it is installed",
    )
    p.add_argument(
        "--stages-from",
        type=Path,
        nargs="+",
        metavar="DIR",
        help="other protocol directories (e.g. the pair's quick one) whose finished "
        "policies, pairs, models and banks (and transfer runs, where the steps per run are "
        "this plan's) are copied in first, in the order given; one whose config differs "
        "from this plan's is redone",
    )
    p.add_argument(
        "--selection-from",
        type=Path,
        metavar="DIR",
        help="a protocol directory (e.g. the pair's quick screen) whose beta and model "
        "selections, made on its tuning seeds, are evaluated here without tuning again",
    )
    p.add_argument(
        "--preregistration",
        type=Path,
        nargs="+",
        metavar="FILE",
        help="at the paper budget, each method beyond the paper needs one: a TOML file "
        "committed to git before its evaluation runs start, fixing its beta and init per "
        "pair (docs/decisions/protocol.md); its selection is the one used",
    )
    p.add_argument(
        "--exploratory",
        action="store_true",
        help="evaluate a method beyond the paper at the paper budget without a valid "
        "pre-registration; its results are marked exploratory",
    )
    # each run's checkpoints by wall time, as transfer's and train-policy's (a kill or a
    # lost node costs a run at most about S seconds)
    v.add_checkpoint_seconds(p)
    p.set_defaults(func=_cmd_protocol)


def add_protocol_status(v: Verbs) -> None:
    # answered by pved.cli.protocol_status before this parser is built (no torch); here
    # so that `pved --help` lists it
    text = status_parser().description
    p = v.sub.add_parser("protocol-status", help=text, description=text)
    p.add_argument("dir", type=Path, metavar="DIR", help="the protocol's --out directory")


def _cmd_batch(args: argparse.Namespace) -> None:
    from pved.checks import check_number, check_writable
    from pved.errors import PvedError
    from pved.protocol import batch

    if args.action == "export":
        if args.max_input_mib is not None:  # a number before it is turned into bytes
            check_number("--max-input-mib", args.max_input_mib, low=0.0, low_open=True)
        keys = batch.export_batch(
            args.protocol,
            args.batch,
            limit=args.limit,
            skip=args.skip,
            claim_minutes=args.claim_minutes,
            max_input_bytes=(
                None if args.max_input_mib is None else int(args.max_input_mib * 2**20)
            ),
        )
        print(f"{args.batch}: {len(keys)} runs")
    elif args.action == "release":
        released = batch.release_batch(args.protocol, args.batch)
        print(f"{len(released)} runs released")
    elif args.action == "run":
        if args.pack is not None:  # found before the runs, not after them
            check_writable("--pack", args.pack)
        log = batch.run_batch(
            args.batch, workers=args.workers, deadline_s=args.deadline_s, start_by_s=args.start_by_s
        )
        states = [entry["state"] for entry in log["jobs"].values()]
        counts = ", ".join(f"{states.count(s)} {s}" for s in sorted(set(states)))
        print(f"{args.batch / batch.LOG_FILE}: {counts} in {log['elapsed_s']:.0f} s")
        if args.pack:
            for path in batch.pack_batch(args.batch, args.pack):
                print(path)
        failed = {k: e["error"] for k, e in log["jobs"].items() if "error" in e}
        if failed:
            key, error = next(iter(failed.items()))
            raise PvedError(f"{len(failed)} of {len(states)} runs failed; {key}: {error}")
    elif args.action == "pack":
        for path in batch.pack_batch(args.batch, args.to):
            print(path)
    else:
        outcome = batch.import_batch(args.protocol, args.sources, finished_only=args.finished_only)
        print(", ".join(f"{len(keys)} {what}" for what, keys in outcome.items()))
        for what in ("mismatch", "unknown"):
            for key in outcome[what]:
                print(f"  {what}: {key}")


def add_batch(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "batch",
        help="run a protocol's transfer runs on a machine that cannot reach it",
        description="export the protocol's transfer runs that can start now into a batch "
        "directory, run it on another machine, pack what it made into tar files, import "
        "those into the protocol (each run's config hash checked).",
    )
    actions = p.add_subparsers(dest="action", required=True)
    a = actions.add_parser(
        "export", help="the runs that can start now, with their models and banks"
    )
    a.add_argument(
        "--protocol",
        type=Path,
        nargs="+",
        required=True,
        help="the protocol directory; several (of different pairs) share one batch",
    )
    a.add_argument("--batch", type=Path, required=True, help="a new batch directory")
    a.add_argument("--limit", type=int, help="at most this many runs (of each protocol)")
    a.add_argument(
        "--skip",
        type=int,
        default=0,
        help="leave out the first N (for a protocol running here that predates claims)",
    )
    a.add_argument(
        "--claim-minutes",
        type=float,
        default=60.0,
        help="claim the exported runs this long: a protocol running here leaves them to "
        "the batch (default 60; 0: no claim)",
    )
    a.add_argument(
        "--max-input-mib",
        type=float,
        help="the models and banks carried at most this many MiB in all: runs whose inputs "
        "do not fit are passed over for later ones (a transport with a size limit)",
    )
    a = actions.add_parser("release", help="end a batch's claims on the runs it did not send back")
    a.add_argument("--protocol", type=Path, required=True, help="the protocol directory")
    a.add_argument("--batch", type=Path, help="only this batch's claims (default: all)")
    a = actions.add_parser("run", help="run a batch's runs side by side")
    a.add_argument("--batch", type=Path, required=True)
    a.add_argument("--workers", type=int, help="runs side by side (default: the CPUs)")
    a.add_argument("--deadline-s", type=float, help="kill what still runs after this")
    a.add_argument("--start-by-s", type=float, help="start no run after this")
    a.add_argument("--pack", type=Path, help="then pack the run directories into this")
    a = actions.add_parser("pack", help="a batch's run directories into tar files")
    a.add_argument("--batch", type=Path, required=True)
    a.add_argument("--to", type=Path, required=True)
    a = actions.add_parser("import", help="a batch's runs into the protocol")
    a.add_argument("--protocol", type=Path, required=True, help="the protocol directory")
    a.add_argument("sources", nargs="+", type=Path, help="tar files or batch directories")
    a.add_argument(
        "--finished-only",
        action="store_true",
        help="leave unfinished runs out (from a batch directory whose run goes on)",
    )
    p.set_defaults(func=_cmd_batch)


def _cmd_archive(args: argparse.Namespace) -> None:
    from pved.protocol import archive

    if args.action == "save":
        counts = archive.save_archive(args.protocol, args.archive)
    elif args.action == "summary":
        counts = archive.save_summary(args.protocol, args.archive)
    else:
        counts = archive.restore_archive(args.archive, args.protocol)
    print(f"{args.archive}: " + ", ".join(f"{n} {what}" for what, n in counts.items()))


def add_archive(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "archive",
        help="a protocol's finished runs, slimmed to commit, and back",
        description="save: copy a protocol's finished policy, model and transfer runs "
        "(results, configs, evaluation curves, models; no checkpoints, datasets or banks) "
        "into a small directory to keep beside the repository; summary: write the finished "
        "transfer runs' results, configs and curves as one file to commit; restore: put "
        "either back into a protocol directory, where `pved protocol` takes them as done "
        "and runs the rest.",
    )
    actions = p.add_subparsers(dest="action", required=True)
    for action, help_text in (
        ("save", "the protocol's finished runs into the archive"),
        ("summary", "the protocol's finished transfer runs into one summary file there"),
        ("restore", "the archive's (or summary's) runs into the protocol directory"),
    ):
        a = actions.add_parser(action, help=help_text)
        a.add_argument("--protocol", type=Path, required=True, help="the protocol directory")
        a.add_argument("--archive", type=Path, required=True, help="the archive directory")
    p.set_defaults(func=_cmd_archive)


def _cmd_plot(args: argparse.Namespace) -> None:
    from pved.protocol.driver import plot_protocols

    for path in plot_protocols(args.dirs, combined=args.out):
        print(path)


def add_plot(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser("plot", help="redraw a protocol's curves and summary from its runs")
    p.add_argument("dirs", nargs="+", type=Path, help="protocol output directories")
    p.add_argument("--out", type=Path, help="with several DIRs: one figure of all their pairs")
    p.set_defaults(func=_cmd_plot)


def _cmd_claims(args: argparse.Namespace) -> None:
    from pved.analysis.claims import write_claims

    md = write_claims(args.dirs, args.out)
    for line in md.read_text().splitlines():
        if line.startswith("## Claim "):
            print(line.removeprefix("## "))
        elif line.startswith("- Warning: "):  # runs of other code's arithmetic compared
            print(line.removeprefix("- "))
    print(md)


def add_claims(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "claims",
        help="verdicts on the paper's seven claims (IV.B) from protocol outputs",
        description="Judge each of the paper's claims about Fig. 3, part by part and pair "
        "by pair, as holds / does not hold / undecided with bootstrap CIs over source "
        "policies and seeds, and family-wise (Holm); writes claims.json and claims.md. "
        "Give each pair's protocol directory once.",
    )
    p.add_argument("dirs", nargs="+", type=Path, help="protocol output directories")
    p.add_argument("--out", type=Path, help="where claims.json/md go (default: the first DIR)")
    p.set_defaults(func=_cmd_claims)


def _cmd_choose(args: argparse.Namespace) -> None:
    import json

    from pved.errors import PvedError
    from pved.protocol.choose import (
        check_registered_budget,
        choice_json,
        choice_table,
        choose,
        write_preregistration,
    )

    # what the file would be refused for is refused before the screens are judged
    if (args.write is None) != (args.budget is None):
        raise PvedError("--write and --budget go together (the file registers one budget)")
    if args.write is not None:
        check_registered_budget(args.budget)
        if args.write.exists():
            raise PvedError(
                f"--write {args.write}: exists; a pre-registration is never overwritten"
            )
    choice = choose(args.dirs, args.candidates or ())
    print(json.dumps(choice_json(choice), indent=2) if args.json else choice_table(choice))
    if args.write is not None:
        pairs = args.pairs or [p for p in choice.standings.get(choice.winner or "", {})]
        print(f"wrote {write_preregistration(choice, args.write, args.budget, pairs)}")


def add_choose(v: Verbs) -> None:
    p = v.sub.add_parser(
        "choose",
        help="issue 64's rule: which method beyond the paper goes to the paper's budget",
        description="Apply the pre-registered rule (docs/decisions/protocol.md) to one "
        "finished screen-auc protocol per pair: a candidate behind PPO in final score on "
        "any pair is out; of the rest the one ahead of PPO in area under the learning "
        "curve on the most pairs goes, ties to the larger mean area difference in units "
        "of each pair's A/A gap. With --write, the winner's beta and init per pair, as "
        "its screens chose them, go to a pre-registration file.",
    )
    p.add_argument("dirs", nargs="+", type=Path, help="screen-auc protocol directories")
    p.add_argument("--candidates", nargs="+", metavar="METHOD", help="default: all screened")
    p.add_argument("--json", action="store_true", help="print the choice as JSON")
    p.add_argument("--write", type=Path, metavar="FILE", help="pre-registration file to write")
    p.add_argument(
        "--budget", help="the paper budget the file registers (paper, paper-45, paper-wide)"
    )
    p.add_argument("--pairs", nargs="+", metavar="PAIR", help="pairs it registers (default: all)")
    p.set_defaults(func=_cmd_choose)


def _cmd_demo(args: argparse.Namespace) -> None:
    import dataclasses

    from pved.checks import given, named_options
    from pved.experiments.demo import DemoConfig, run_demo

    seeds = None if args.seeds is None else tuple(args.seeds)
    with named_options(transfer_steps="--steps", seeds="--seeds", jobs="--jobs"):
        cfg = dataclasses.replace(
            DemoConfig(), **given(transfer_steps=args.steps, seeds=seeds, jobs=args.jobs)
        )
    out = run_demo(args.runs, args.out, cfg)
    print((out / "results.md").read_text())
    print(f"report: {out.resolve()}")


def add_demo(v: Verbs) -> None:
    add = v.add

    p = add("demo", "the Reacher pair end to end on the demo budget", "runs/demo")
    p.add_argument("--out", type=Path, default=Path("reports/reacher-demo"))
    p.add_argument("--steps", type=int, help="transfer env steps per run")
    p.add_argument("--seeds", nargs="+", type=int)
    p.add_argument("--jobs", type=int)
    p.set_defaults(func=_cmd_demo)


def _cmd_fingerprint(args: argparse.Namespace) -> None:
    from pved.commands import print_json
    from pved.errors import PvedError
    from pved.experiments.fingerprint import check_fingerprint, mismatch_message, write_pins

    check = check_fingerprint()
    if args.json:
        print_json(check)
    else:
        for stage, digest in check["digests"].items():
            print(f"{stage}: {digest} (pinned {check['pinned']['digests'].get(stage, '-')})")
        print(f"id: {check['id']} (pinned {check['pinned']['id']})")
        print("matches the pins" if check["matches"] else "differs from the pins")
    if args.pin:
        write_pins(check["digests"])
        print(f"pinned: {check['id']}")
    elif not check["matches"]:
        raise PvedError(mismatch_message(check))


def add_fingerprint(v: Verbs) -> None:
    p = v.sub.add_parser(
        "fingerprint",
        help="the numeric fingerprint: three short runs' digests against their pins",
        description="Run a short PPO run, a short PVED fit and a short Eq. 10 shaped run "
        "(seconds on one core), print each one's digest, the fingerprint id runs record, "
        "and whether they match the pins in src/pved/fingerprint_pins.json; exit status 2 "
        "when they do not.",
    )
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument(
        "--pin",
        action="store_true",
        help="write these digests into the pin file (for the commit that changes the "
        "numbers on purpose; its message names the records it invalidates)",
    )
    p.set_defaults(func=_cmd_fingerprint)


VERBS = (
    add_protocol,
    add_protocol_status,
    add_batch,
    add_archive,
    add_plot,
    add_claims,
    add_choose,
    add_demo,
    add_fingerprint,
)
