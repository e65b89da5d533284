"""``pved <verb>``: thin command-line layer over :mod:`pved.experiments.stages`.

Every verb calls the Python function of the same name with the same arguments. Bad
input (an unknown name, mismatched dims, a corrupt file, NaN in training) prints one
line ``pved: error: ...`` and exits with status 2; results are only ever written
atomically, so nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn


class _Parser(argparse.ArgumentParser):
    """argparse, with its refusals (a value of the wrong type, a missing or unknown
    option) as one ``pved: error:`` line and exit status 2, like every other refusal,
    rather than the usage text and a second line."""

    def error(self, message: str) -> NoReturn:
        from pved.errors import PvedError

        raise PvedError(f"{message} (see: {self.prog} --help)")


def _print_json(obj: Any) -> None:
    from pved.runs import to_jsonable

    print(json.dumps(to_jsonable(obj), indent=2))


def _cmd_list(args: argparse.Namespace) -> None:
    from pved.config import PRESETS
    from pved.envs.registry import registered_env_ids
    from pved.models import MODELS

    print("pairs:  " + ", ".join(sorted(PRESETS)))
    print("models: " + ", ".join(sorted(MODELS)))
    print("transfer methods: the models, ppo (no transfer), oracle (source's full reward)")
    print("envs:   " + ", ".join(registered_env_ids()))


def _cmd_train_policy(args: argparse.Namespace) -> None:
    from pved.experiments.stages import train_policy

    path = train_policy(
        args.agent,
        args.task,
        seed=args.seed,
        steps=args.steps,
        reward=args.reward,
        runs_root=args.runs,
        eval_episodes=args.eval_episodes,
        checkpoint_every_s=args.checkpoint_seconds,
        pair=args.pair,
    )
    print(path)


def _cmd_collect_pairs(args: argparse.Namespace) -> None:
    from pved.experiments.stages import collect_pairs

    print(
        collect_pairs(
            args.pair,
            source_policy=args.source_policy,
            target_policy=args.target_policy,
            episodes=args.episodes,
            seed=args.seed,
            align=args.align,
            task=args.task,
            runs_root=args.runs,
        )
    )


def _cmd_train_model(args: argparse.Namespace) -> None:
    from pved.experiments.stages import train_model

    print(
        train_model(
            args.pair,
            args.model,
            dataset=args.dataset,
            seed=args.seed,
            epochs=args.epochs,
            runs_root=args.runs,
        )
    )


def _cmd_build_bank(args: argparse.Namespace) -> None:
    from pved.experiments.stages import build_bank

    print(
        build_bank(
            args.pair,
            source_policy=args.source_policy,
            episodes=args.episodes,
            seed=args.seed,
            runs_root=args.runs,
        )
    )


def _cmd_transfer(args: argparse.Namespace) -> None:
    from pved.experiments.stages import transfer

    _print_json(
        transfer(
            args.pair,
            args.model,
            seed=args.seed,
            model_path=args.model_path,
            bank_path=args.bank,
            steps=args.steps,
            beta=args.beta,
            eval_every=args.eval_every,
            eval_episodes=args.eval_episodes,
            final_eval_episodes=args.final_eval_episodes,
            runs_root=args.runs,
            shaping_start=args.shaping_start,
            shaping_form=args.shaping_form,
            shaping_action=args.shaping_action,
            checkpoint_every_s=args.checkpoint_seconds,
        )
    )


def _cmd_evaluate(args: argparse.Namespace) -> None:
    from pved.experiments.stages import evaluate

    _print_json(
        evaluate(
            args.policy,
            args.env,
            episodes=args.episodes,
            seed=args.seed,
            reward=args.reward,
            pair=args.pair,
        )
    )


def _cmd_pair(args: argparse.Namespace) -> None:
    from pved.spec import dump_pair, load_pair

    if args.action == "show":
        print(dump_pair(load_pair(args.spec)), end="")
    else:
        from pved.experiments.pair_check import check_pair

        print(check_pair(args.spec, args.runs))


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


def _cmd_report(args: argparse.Namespace) -> None:
    from pved.errors import PvedError

    if args.inputs:
        from pved.analysis.pair_report import build_pair_report

        # The runs-mode options would be silently ignored here; say so instead.
        if args.seeds is not None or args.methods is not None:
            raise PvedError("--seeds and --methods are for the report of runs, not with DIRs")
        print(build_pair_report(args.pair, args.inputs, args.out, videos=not args.no_videos))
        return
    from pved.analysis.report import transfer_report
    from pved.config import get_preset

    if args.seeds is None or args.out is None:
        raise PvedError(
            "report needs DIR... (the full pair report) or --seeds and --out (a report of runs)"
        )
    preset = get_preset(args.pair)
    title = f"{preset.source_agent} -> {preset.target_agent} on {preset.target_task}"
    print(
        transfer_report(
            args.pair,
            args.methods or ["pved", "ppo"],
            args.seeds,
            args.runs,
            args.out,
            metric=preset.metric,
            title=title,
        )
    )


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


def _cmd_protocol(args: argparse.Namespace) -> None:
    from pved.experiments.protocol import run_protocol

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
    )
    failed = len(summary["failed"]) + len(summary["blocked"])
    print(f"{args.out / 'summary.md'} ({failed} runs failed or blocked)")


def _cmd_batch(args: argparse.Namespace) -> None:
    from pved.checks import check_number, check_writable
    from pved.errors import PvedError
    from pved.experiments import batch

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


def _cmd_archive(args: argparse.Namespace) -> None:
    from pved.experiments import archive

    if args.action == "save":
        counts = archive.save_archive(args.protocol, args.archive)
    elif args.action == "summary":
        counts = archive.save_summary(args.protocol, args.archive)
    else:
        counts = archive.restore_archive(args.archive, args.protocol)
    print(f"{args.archive}: " + ", ".join(f"{n} {what}" for what, n in counts.items()))


def _cmd_plot(args: argparse.Namespace) -> None:
    from pved.experiments.protocol import plot_protocols

    for path in plot_protocols(args.dirs, combined=args.out):
        print(path)


def _cmd_claims(args: argparse.Namespace) -> None:
    from pved.analysis.claims import write_claims

    md = write_claims(args.dirs, args.out)
    for line in md.read_text().splitlines():
        if line.startswith("## Claim "):
            print(line.removeprefix("## "))
    print(md)


def _cmd_tsne(args: argparse.Namespace) -> None:
    from pved.experiments.stages import analyze_subspaces

    result = analyze_subspaces(
        args.pair,
        args.model,
        args.target_policy,
        args.out,
        source_policy=args.source_policy,
        episodes=args.episodes,
        marks=args.marks,
        seed=args.seed,
        target_later_frames=args.later_frames,
        later_frame_stride=args.later_frame_stride,
    )
    _print_json(result["numbers"])
    print(f"figures: {Path(args.out).resolve()}")


def _cmd_bound(args: argparse.Namespace) -> None:
    from pved.experiments.stages import bound

    result = bound(
        args.pair,
        args.model,
        args.target_policy,
        source_policy=args.source_policy,
        episodes=args.episodes,
        quantile=args.quantile,
        gamma=args.gamma,
        seed=args.seed,
    )
    print(result["summary"])


def _cmd_audit_shaping(args: argparse.Namespace) -> None:
    from pved.analysis.shaping_audit import audit_pair
    from pved.experiments.stages import run_file

    _print_json(
        audit_pair(
            args.pair,
            run_file(args.model, "model.pt", "model"),
            run_file(args.bank, "bank.npz", "source bank"),
            steps=args.steps,
            betas=args.betas,
            seed=args.seed,
            out=args.out,
        )
    )


def _cmd_audit_likelihood(args: argparse.Namespace) -> None:
    from pved.analysis.shaping_audit import likelihood_reading
    from pved.experiments.stages import run_file

    _print_json(
        likelihood_reading(
            args.pair,
            run_file(args.dataset, "pairs.npz", "dataset"),
            seed=args.seed,
            epochs=args.epochs,
            runs_root=args.runs,
            out=args.out,
        )
    )


def _cmd_video(args: argparse.Namespace) -> None:
    from pved.analysis.video import render_rollout
    from pved.errors import PvedError
    from pved.experiments.stages import run_file

    other = None
    if args.with_policy is not None:
        if args.with_env is None:
            raise PvedError("--with-policy needs --with-env")
        other = (run_file(args.with_policy, "policy.pt"), args.with_env)
    path = render_rollout(
        run_file(args.policy, "policy.pt"),
        args.env,
        args.out,
        seed=args.seed,
        max_steps=args.max_steps,
        side_by_side_with=other,
    )
    print(path)


def _cmd_analyze(args: argparse.Namespace) -> None:
    from pved.errors import PvedError

    if args.analysis == "subspaces":
        from pved.analysis.subspaces import subspaces_report

        subspaces_report(args.protocol, args.pair, episodes=args.episodes, videos=args.videos)
        print(args.protocol / "subspaces")
        return
    if args.analysis == "shaping-scale":
        from pved.analysis.shaping_scale import protocol_shaping_scale

        tables = protocol_shaping_scale(args.protocol, rows=args.rows, seed=args.seed)[1]
        out = args.protocol / "subspaces" / "shaping_scale.json"
    elif args.analysis == "source-reading":
        from pved.analysis.source_reading import protocol_source_reading

        tables = protocol_source_reading(args.protocol)[1]
        out = args.protocol / "subspaces" / "source_reading.json"
    elif args.analysis == "peg-success":
        from pved.analysis.peg_success import peg_success

        tables = peg_success(
            args.path,
            args.agent,
            args.grid,
            args.copies,
            args.seed,
            args.json,
            args.shaping_model,
            args.bank,
        )[1]
        is_protocol = (args.path / "protocol.json").is_file()
        out = args.json or (args.path / "subspaces" / "peg_success.json" if is_protocol else None)
    else:
        from pved.analysis.pairing_signal import compare_datasets, protocol_pairing_signal

        # the dataset options measure datasets, not a protocol: say so rather than ignore them
        if not args.datasets and (
            args.model or args.bank or args.repair or args.first_episodes is not None
        ):
            raise PvedError("--model, --bank, --repair and --first-episodes go with --datasets")
        if args.bank and not args.model:
            raise PvedError("--bank needs --model")
        if args.datasets:
            print(
                compare_datasets(
                    args.datasets,
                    args.first_episodes,
                    args.rows,
                    args.code_rows,
                    args.seed,
                    args.model,
                    args.bank,
                    args.repair,
                )
            )
            return
        if args.protocol is None:
            raise PvedError("give a protocol directory or --datasets")
        tables = protocol_pairing_signal(
            args.protocol, args.rows, args.code_rows, args.alpha3, args.seed
        )[1]
        out = args.protocol / "subspaces" / "pairing_signal.json"
    print(tables)
    if out is not None:
        print(out)


def _cmd_compare(args: argparse.Namespace) -> None:
    from pved.analysis.compare import compare_runs, format_comparison
    from pved.checks import check_writable
    from pved.runs import atomic_write_json

    if args.json is not None:
        check_writable("--json", args.json, directory=False)
    result = compare_runs(args.a, args.b, (args.names[0], args.names[1]))
    if args.json is not None:
        atomic_write_json(args.json, result)
    print(format_comparison(result))


def build_parser() -> argparse.ArgumentParser:
    """The ``pved`` argument parser (sub-commands)."""
    # the names a choice takes, from the registries that check them (each checks its own
    # and names the known ones in a one-line error, so argparse's `choices` is not used)
    from pved.config import BUDGETS, PRESETS
    from pved.envs.registry import AGENTS, TASKS
    from pved.experiments.stages import REFERENCE_METHODS
    from pved.models import MODELS
    from pved.pairing.align import ALIGNMENTS

    pairs = " | ".join(sorted(PRESETS))
    models = " | ".join(sorted(MODELS))
    methods = f"{models} | {' | '.join(REFERENCE_METHODS)}"
    pair_help = f"{pairs}, or a pair spec file (.toml; docs/pairs.md) (default: %(default)s)"
    pair_tasks = "; ".join(
        f"{name}: {preset.training_task} | {preset.target_task}"
        for name, preset in sorted(PRESETS.items())
    )

    from pved.rl.ppo import CHECKPOINT_SECONDS

    parser: argparse.ArgumentParser = _Parser(
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

    def add(name: str, help_text: str, runs_default: str = "runs") -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.add_argument(
            "--runs",
            type=Path,
            default=Path(runs_default),
            help="root of the run directories (default: %(default)s)",
        )
        return p

    p = sub.add_parser("list", help="list the pairs, models and environments")
    p.set_defaults(func=_cmd_list)

    p = add("train-policy", "PPO for any agent on any task, with a seed")
    p.add_argument("--agent", required=True, help=" | ".join(AGENTS) + ", or a spec's agent")
    p.add_argument("--task", required=True, help=" | ".join(TASKS) + ", or a spec's task")
    p.add_argument(
        "--pair",
        help="the pair (a name or a spec file) whose env and PPO config the agent's task "
        "takes (default: the first pair the agent is in)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, help="env steps (default: the preset's)")
    p.add_argument("--reward", help="env reward variant, e.g. full")
    p.add_argument(
        "--eval-episodes", type=int, help="episodes per evaluation (default: the preset's)"
    )
    add_checkpoint_seconds(p)
    p.set_defaults(func=_cmd_train_policy)

    p = add("collect-pairs", "paired rollouts of both agents on the training task")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--source-policy",
        type=Path,
        help="policy.pt or its run directory (default: the shipped pretrained one)",
    )
    p.add_argument(
        "--target-policy",
        type=Path,
        help="policy.pt or its run directory (default: the shipped pretrained one)",
    )
    p.add_argument("--episodes", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--align",
        help=f"{' | '.join(ALIGNMENTS)}: subsample (paper IV.A), time (same physical time), "
        "dtw (rounds of DTW on the shared space) or phase (same moment of the stride, near "
        "the same time); default: the pair's",
    )
    p.add_argument(
        "--task",
        help="the task to pair the agents on: the pair's training task (default) or, for "
        f"analysis and not as in the paper, its target task (give both policies); {pair_tasks}",
    )
    p.set_defaults(func=_cmd_collect_pairs)

    p = add("train-model", "fit PVED (or a variant) on a paired dataset")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", default="pved", help=f"{models} (default: %(default)s)")
    p.add_argument(
        "--dataset",
        type=Path,
        help="pairs.npz or its run directory (default: the pair's collect-pairs output)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int)
    p.set_defaults(func=_cmd_train_model)

    p = add("build-bank", "roll out the source's target-task policy for the shaping term")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--source-policy",
        type=Path,
        help="policy.pt or its run directory (default: the shipped pretrained one)",
    )
    p.add_argument("--episodes", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_build_bank)

    p = add("transfer", "PPO of the target agent with the Eq. 10 shaping (or --model ppo)")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--model",
        default="pved",
        help=f"{methods}: a model (shaping), ppo (no transfer) or oracle (the source's full "
        "reward); default: %(default)s",
    )
    p.add_argument("--seed", type=int, default=20000)
    p.add_argument(
        "--model-path",
        type=Path,
        help="model.pt or its run directory (default: the pair's train-model output)",
    )
    p.add_argument(
        "--bank",
        type=Path,
        help="bank.npz or its run directory (default: the pair's build-bank output)",
    )
    p.add_argument("--steps", type=int)
    p.add_argument("--beta", type=float)
    p.add_argument("--eval-every", type=int)
    p.add_argument("--eval-episodes", type=int)
    p.add_argument("--final-eval-episodes", type=int)
    p.add_argument(
        "--shaping-start",
        type=int,
        default=0,
        metavar="STEPS",
        help="hold the shaping term at 0 for the first STEPS env steps (not in the paper; "
        "default 0: from the start)",
    )
    p.add_argument(
        "--shaping-form",
        default="eq10",
        metavar="FORM",
        help="eq10: the paper's -beta*D (default); log1p: -beta*log(1+D), which keeps the "
        "term's ordering but compresses its range (not in the paper)",
    )
    p.add_argument(
        "--shaping-action",
        default="mean",
        choices=("mean", "taken"),
        help="the target action Eq. 10 encodes: mean (the policy's mean action, as in the "
        "pairs and the bank; default) or taken (the sampled exploration action)",
    )
    add_checkpoint_seconds(p)
    p.set_defaults(func=_cmd_transfer)

    p = sub.add_parser("evaluate", help="success rate / return of a saved policy")
    p.add_argument("--policy", type=Path, required=True, help="policy.pt or its run directory")
    p.add_argument(
        "--env",
        help="env id (with --pair: one of its envs; default its target agent's on the target task)",
    )
    p.add_argument("--pair", help="a pair (name or spec file): its env arguments and metric")
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--reward")
    p.set_defaults(func=_cmd_evaluate)

    p = add(
        "report",
        "learning curves and a results table for transfer runs; with DIRs, the full pair "
        "report: one self-contained HTML file",
    )
    p.description = (
        "Without DIR: learning curves, results.md/json and configs of the transfer runs "
        "under --runs (needs --seeds and --out). With DIR...: the full report of --pair as "
        "one HTML file with every image and video embedded, from the outputs of other "
        "verbs: protocol directories, runs-mode report folders, `pved tsne --out` folders, "
        "bound files (`pved bound ... > bound.txt`) and videos (.gif/.mp4/.webm, also "
        "anywhere under a DIR). Give the DIRs together, before or after the options."
    )
    p.add_argument(
        "inputs",
        nargs="*",
        type=Path,
        metavar="DIR",
        help="pved outputs of the pair (directories or files); gives the full pair report",
    )
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--methods", nargs="+", help=f"runs mode: {methods} (default: pved ppo)")
    p.add_argument("--seeds", nargs="+", type=int, help="runs mode: transfer seeds (required)")
    p.add_argument(
        "--out",
        type=Path,
        help="runs mode: the report folder (required); with DIRs: the HTML file "
        "(default: reports/<pair>-report.html)",
    )
    p.add_argument(
        "--no-videos",
        action="store_true",
        help="with a protocol DIR: do not render one rollout per method",
    )
    p.set_defaults(func=_cmd_report)

    p = sub.add_parser(
        "tsne", help="t-SNE of the shared and individual subspaces along rollouts (Figs. 4-7)"
    )
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", type=Path, required=True, help="model.pt or its run directory")
    p.add_argument(
        "--target-policy",
        type=Path,
        required=True,
        help="the transferred target's policy.pt or its transfer run directory",
    )
    p.add_argument("--source-policy", type=Path, help="default: the shipped target-task one")
    p.add_argument("--episodes", type=int, default=6)
    p.add_argument("--marks", type=int, default=4, help="marked positions with their frames")
    p.add_argument(
        "--later-frames",
        type=int,
        metavar="N",
        help="later target frames per mark, as the paper shows for Ant "
        "(default: 2 when the target agent is Ant, else 0)",
    )
    p.add_argument(
        "--later-frame-stride",
        type=int,
        metavar="STEPS",
        help="control steps between the later frames (default: 5)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(func=_cmd_tsne)

    p = sub.add_parser("bound", help="Theorem 1 / Corollary 1 against the measured gap")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", type=Path, required=True, help="model.pt or its run directory")
    p.add_argument("--target-policy", type=Path, required=True)
    p.add_argument("--source-policy", type=Path, help="default: the shipped target-task one")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument(
        "--quantile",
        type=float,
        default=0.95,
        help="a quantile of the KL reported beside δ (Theorem 1's δ is the max KL)",
    )
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_bound)

    p = sub.add_parser(
        "audit-shaping",
        help="Eq. 10 at the start of a transfer run: mean vs sampled action, reward clip",
        description="On rollouts of a fresh transfer policy: D with the mean and with the "
        "sampled action on the same states, how often PPO's reward clip binds with the "
        "normaliser on env reward + shaping and on the env reward alone, per beta.",
    )
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", type=Path, required=True, help="model.pt or its run directory")
    p.add_argument("--bank", type=Path, required=True, help="bank.npz or its run directory")
    p.add_argument("--steps", type=int, default=32_768, help="env steps of the rollout")
    p.add_argument("--betas", type=float, nargs="+", help="default: the pair's beta grid")
    p.add_argument("--seed", type=int, default=2000, help="the transfer run's PPO seed")
    p.add_argument("--out", type=Path, help="also write the JSON here")
    p.set_defaults(func=_cmd_audit_shaping)

    p = sub.add_parser(
        "audit-likelihood",
        help="Eq. 10's scale under a learned and a unit decoder variance",
        description="Fits the pair's PVED with the learned per-dimension decoder variance "
        "and with a unit one on the same pairs, and reports D on matched and shuffled "
        "training pairs for each.",
    )
    p.add_argument("--runs", type=Path, default=Path("runs"), help="root of the run directories")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--dataset", type=Path, required=True, help="pairs.npz or its run directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, help="default: the pair's")
    p.add_argument("--out", type=Path, help="also write the JSON here")
    p.set_defaults(func=_cmd_audit_likelihood)

    p = sub.add_parser("video", help="render a rollout of a policy to GIF (or MP4)")
    p.add_argument("--policy", type=Path, required=True, help="policy.pt or its run directory")
    p.add_argument("--env", required=True)
    p.add_argument("--with-policy", type=Path, help="a second policy shown beside the first")
    p.add_argument("--with-env", help="the second policy's env id")
    p.add_argument("--max-steps", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(func=_cmd_video)

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
        help=f"{' | '.join(BUDGETS)} (paper-wide: 81 evaluation runs); default: %(default)s",
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
        help="another protocol directory (e.g. the pair's quick one) whose finished "
        "policies, pairs, models and banks are copied in first; one whose config differs "
        "from this plan's is redone",
    )
    p.set_defaults(func=_cmd_protocol)

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

    p = sub.add_parser("plot", help="redraw a protocol's curves and summary from its runs")
    p.add_argument("dirs", nargs="+", type=Path, help="protocol output directories")
    p.add_argument("--out", type=Path, help="with several DIRs: one figure of all their pairs")
    p.set_defaults(func=_cmd_plot)

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

    p = sub.add_parser(
        "compare",
        help="two groups of transfer runs: final, early and drop differences with 95%% CIs",
        description="Compare the finished transfer runs under --a with those under --b, "
        "as `pved claims` compares two methods: the difference A - B of the final score, "
        "the early score and the drop, each with its 95% bootstrap CI over source banks "
        "and PPO seeds (every run of a drawn bank and seed taken) and p-value, and the "
        "steps each group's mean curve takes to reach B's final mean. A DIR is a run "
        "directory or a folder searched for them.",
    )
    p.add_argument("--a", nargs="+", type=Path, required=True, metavar="DIR")
    p.add_argument("--b", nargs="+", type=Path, required=True, metavar="DIR")
    p.add_argument("--names", nargs=2, default=["A", "B"], metavar=("NAME_A", "NAME_B"))
    p.add_argument("--json", type=Path, help="also write the numbers here (atomically)")
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser(
        "analyze",
        help="what a finished protocol's runs say (`make subspaces` runs these)",
        description="Analyses of a finished `pved protocol` directory; each writes its "
        "JSON under PROTOCOL_DIR/subspaces/ and prints Markdown tables.",
    )
    analyses = p.add_subparsers(dest="analysis", required=True, metavar="ANALYSIS")
    a = analyses.add_parser(
        "subspaces",
        help="t-SNE, Theorem 1's bound and the HTML report of PVED's best evaluation run",
    )
    a.add_argument("protocol", type=Path, metavar="PROTOCOL_DIR")
    a.add_argument("--pair", help="the pair (default: the directory's only one)")
    a.add_argument("--episodes", type=int, default=4, help="rollouts per agent (default 4)")
    a.add_argument("--videos", action="store_true", help="embed one rollout per method")
    a = analyses.add_parser(
        "shaping-scale",
        help="Eq. 10's distance on matched and unrelated training pairs, and along the runs",
    )
    a.add_argument("protocol", type=Path, metavar="PROTOCOL_DIR")
    a.add_argument("--rows", type=int, default=20_000, help="training pairs sampled")
    a.add_argument("--seed", type=int, default=0)
    a = analyses.add_parser(
        "pairing-signal",
        help="how much the pairing relates the two agents, and what the shared codes hold",
    )
    a.add_argument("protocol", type=Path, nargs="?", metavar="PROTOCOL_DIR")
    a.add_argument(
        "--datasets",
        type=Path,
        nargs="+",
        default=[],
        help="instead of a protocol: only the pairing's R², of each of these paired datasets",
    )
    a.add_argument(
        "--first-episodes", type=int, help="with --datasets: only episodes 0..N-1 of each"
    )
    a.add_argument("--model", type=Path, help="with --datasets: also this model's codes")
    a.add_argument("--bank", type=Path, help="with --model: the source bank on the target task")
    a.add_argument(
        "--repair",
        action="store_true",
        help="with --datasets: also the R² after re-pairing rows by phase, and two controls",
    )
    a.add_argument("--rows", type=int, default=100_000, help="paired rows for the R²")
    a.add_argument("--code-rows", type=int, default=20_000, help="rows for KLs and D")
    a.add_argument("--alpha3", type=float, nargs="*", default=[], help="refit PVED at these")
    a.add_argument("--seed", type=int, default=0)
    a = analyses.add_parser(
        "source-reading",
        help="each shaped method by source policy, and its tuning score against evaluation",
    )
    a.add_argument("protocol", type=Path, metavar="PROTOCOL_DIR")
    a = analyses.add_parser(
        "peg-success",
        help="where on the table a Peg policy (or each of a jaco-fetch protocol's) succeeds",
    )
    a.add_argument(
        "path",
        type=Path,
        metavar="POLICY_OR_PROTOCOL_DIR",
        help="policy.pt, the run directory holding it, or a jaco-fetch protocol directory",
    )
    a.add_argument("--agent", default="fetch4", help="fetch4 (default) or jaco")
    a.add_argument("--grid", type=int, default=11, help="hole positions a side")
    a.add_argument("--copies", type=int, default=8, help="episodes per hole position")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--json", type=Path, help="also write the result here")
    a.add_argument("--shaping-model", type=Path, help="model.pt or its run directory")
    a.add_argument("--bank", type=Path, help="bank.npz or its run directory")
    p.set_defaults(func=_cmd_analyze)

    p = sub.add_parser("pair", help="show or check a pair spec (docs/pairs.md)")
    actions = p.add_subparsers(dest="action", required=True)
    a = actions.add_parser("show", help="print a pair's spec file (a built-in name or a file)")
    a.add_argument("spec", help=f"{pairs}, or a spec file")
    a = actions.add_parser(
        "check",
        help="make each env of a spec, check its robot-state indices, task keys, metric and "
        "policies' dims, and print both agents' dims and what will be paired",
    )
    a.add_argument("spec", help=f"a spec file, or {pairs}")
    a.add_argument(
        "--runs",
        type=Path,
        default=Path("runs"),
        help="where the pair's trained policies are looked for (default: %(default)s)",
    )
    p.set_defaults(func=_cmd_pair)

    p = add("demo", "the Reacher pair end to end on the demo budget", "runs/demo")
    p.add_argument("--out", type=Path, default=Path("reports/reacher-demo"))
    p.add_argument("--steps", type=int, help="transfer env steps per run")
    p.add_argument("--seeds", nargs="+", type=int)
    p.add_argument("--jobs", type=int)
    p.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pved`` console script."""
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
