"""The analyses' verbs: reports, figures and readings of what the runs learned.

Each verb is a handler (``_cmd_<verb>``: the stage it calls, with the parsed options)
and beside it the function that adds its parser (``add_<verb>``).

Just past 600 lines on purpose: one idea, the analyses' command line, every part of it a
short handler and its parser; split by verb, each half would be the same idea again.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pved.commands import Verbs, print_json


def _cmd_report(args: argparse.Namespace) -> None:
    from pved.errors import PvedError

    if args.inputs:
        from pved.diagnostics.pair_report import build_pair_report

        # The runs-mode options would be silently ignored here; say so instead.
        if args.seeds is not None or args.methods is not None:
            raise PvedError("--seeds and --methods are for the report of runs, not with DIRs")
        print(build_pair_report(args.pair, args.inputs, args.out, videos=not args.no_videos))
        return
    from pved.analysis.report import transfer_report
    from pved.spec import get_preset

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


def add_report(v: Verbs) -> None:
    add, pair_help, methods = v.add, v.pair_help, v.methods

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


def _cmd_tsne(args: argparse.Namespace) -> None:
    from pved.diagnostics.transferred import analyze_subspaces

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
    print_json(result["numbers"])
    print(f"figures: {Path(args.out).resolve()}")


def add_tsne(v: Verbs) -> None:
    pair_help, sub = v.pair_help, v.sub

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


def _cmd_bound(args: argparse.Namespace) -> None:
    from pved.diagnostics.transferred import bound

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


def add_bound(v: Verbs) -> None:
    pair_help, sub = v.pair_help, v.sub

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


def _cmd_power(args: argparse.Namespace) -> None:
    from pved.analysis.judge import load_pairs
    from pved.analysis.power import power_rows, power_table
    from pved.errors import PvedError

    if args.runs < 1 or any(k < 2 or args.runs % k for k in args.sources):
        raise PvedError(f"--runs {args.runs} does not split evenly among --sources {args.sources}")
    if args.datasets < 1 or args.reps < 1:
        raise PvedError(f"--datasets and --reps must be positive, got {args.datasets}, {args.reps}")
    pairs = load_pairs(args.protocols)
    rows = power_rows(
        pairs, args.runs, args.sources, args.methods, args.datasets, args.reps, args.seed
    )
    print(power_table(rows))


def add_power(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "power",
        help="the smallest gain over PPO the two-level verdicts find (80%% power), by sources",
    )
    p.add_argument("protocols", nargs="+", type=Path, metavar="DIR", help="protocol directories")
    p.add_argument("--runs", type=int, default=45, help="runs of a method (and of PPO)")
    p.add_argument(
        "--sources", nargs="+", type=int, default=[3, 5, 9], help="source policies to split them"
    )
    p.add_argument(
        "--methods", nargs="+", default=None, help="shaped methods whose runs are the pilot (all)"
    )
    p.add_argument("--datasets", type=int, default=200, help="simulated data sets per design")
    p.add_argument("--reps", type=int, default=2000, help="bootstrap resamples per data set")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated data sets")
    p.set_defaults(func=_cmd_power)


def _cmd_prior_policy(args: argparse.Namespace) -> None:
    from pved.diagnostics.prior_policy import prior_policy

    result = prior_policy(args.pair, args.model, args.bank, episodes=args.episodes, seed=args.seed)
    if args.json:
        print_json(result)
    else:
        print(result["summary"])


def add_prior_policy(v: Verbs) -> None:
    pair_help, sub = v.pair_help, v.sub

    p = sub.add_parser(
        "prior-policy",
        help="act out pved-prior's decoded prior on the target task, beside zero and random "
        "actions",
    )
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", type=Path, required=True, help="a PVED model.pt or its run directory")
    p.add_argument("--bank", type=Path, required=True, help="bank.npz or its run directory")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print every number as JSON")
    p.set_defaults(func=_cmd_prior_policy)


def _cmd_audit_shaping(args: argparse.Namespace) -> None:
    from pved.diagnostics.shaping_audit import audit_pair
    from pved.runs import run_file

    policy = None if args.policy is None else run_file(args.policy, "policy.pt", "policy")
    print_json(
        audit_pair(
            args.pair,
            run_file(args.model, "model.pt", "model"),
            run_file(args.bank, "bank.npz", "source bank"),
            steps=args.steps,
            betas=args.betas,
            seed=args.seed,
            policy_path=policy,
            min_rows=args.min_rows,
            out=args.out,
        )
    )


def add_audit_shaping(v: Verbs) -> None:
    pair_help, sub = v.pair_help, v.sub

    p = sub.add_parser(
        "audit-shaping",
        help="Eq. 10 at the start of a transfer run: mean vs sampled action, reward clip",
        description="On rollouts of a fresh transfer policy (or --policy): D with the mean "
        "and with the sampled action on the same states, how often PPO's reward clip binds "
        "with the normaliser on env reward + shaping and on the env reward alone, per "
        "beta, and how much of D the best action at each state would remove.",
    )
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument("--model", type=Path, required=True, help="model.pt or its run directory")
    p.add_argument("--bank", type=Path, required=True, help="bank.npz or its run directory")
    p.add_argument("--steps", type=int, default=32_768, help="env steps of the rollout")
    p.add_argument("--betas", type=float, nargs="+", help="default: the pair's beta grid")
    p.add_argument("--seed", type=int, default=2000, help="the transfer run's PPO seed")
    p.add_argument(
        "--policy",
        type=Path,
        help="policy.pt or its run directory: roll out this trained policy, not a fresh one",
    )
    p.add_argument(
        "--min-rows",
        type=int,
        default=2048,
        help="rows on which D is minimised over actions (how much of D the action can "
        "remove); 0: none",
    )
    p.add_argument("--out", type=Path, help="also write the JSON here")
    p.set_defaults(func=_cmd_audit_shaping)


def _cmd_audit_likelihood(args: argparse.Namespace) -> None:
    from pved.diagnostics.shaping_audit import likelihood_reading
    from pved.runs import run_file

    print_json(
        likelihood_reading(
            args.pair,
            run_file(args.dataset, "pairs.npz", "dataset"),
            seed=args.seed,
            epochs=args.epochs,
            runs_root=args.runs,
            out=args.out,
        )
    )


def add_audit_likelihood(v: Verbs) -> None:
    pair_help, sub = v.pair_help, v.sub

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


def _cmd_video(args: argparse.Namespace) -> None:
    from pved.diagnostics.video import render_rollout
    from pved.errors import PvedError
    from pved.runs import run_file

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


def add_video(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser("video", help="render a rollout of a policy to GIF (or MP4)")
    p.add_argument("--policy", type=Path, required=True, help="policy.pt or its run directory")
    p.add_argument("--env", required=True)
    p.add_argument("--with-policy", type=Path, help="a second policy shown beside the first")
    p.add_argument("--with-env", help="the second policy's env id")
    p.add_argument("--max-steps", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(func=_cmd_video)


def _cmd_compare(args: argparse.Namespace) -> None:
    from pved.analysis.compare import compare_runs, format_comparison
    from pved.checks import check_writable
    from pved.runs import atomic_write_json

    if args.json is not None:
        check_writable("--json", args.json, directory=False)
    result = compare_runs(args.a, args.b, (args.names[0], args.names[1]), aa=args.aa)
    if args.json is not None:
        atomic_write_json(args.json, result)
    print(format_comparison(result))


def add_compare(v: Verbs) -> None:
    sub = v.sub

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
    p.add_argument(
        "--aa",
        nargs="+",
        type=Path,
        metavar="DIR",
        help="the A/A set: runs made as --b's were, on other seeds; each difference is "
        "shown beside AA - B and flagged 'inside A/A noise' where it is no larger",
    )
    p.add_argument("--json", type=Path, help="also write the numbers here (atomically)")
    p.set_defaults(func=_cmd_compare)


def _cmd_scoreboard(args: argparse.Namespace) -> None:
    from pved.analysis.scoreboard import write_scoreboard

    print(write_scoreboard(args.method, args.dirs, args.out), end="")


def add_scoreboard(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "scoreboard",
        help="one method against PPO, PVED and the oracle on every pair, and the goal",
        description="Per pair, the final score of ppo, pved, METHOD and the oracle with 95%% "
        "CIs (two-level bootstrap over source policies and seeds, as `pved claims`), "
        "METHOD - ppo and the steps METHOD takes to reach ppo's final; then whether "
        "METHOD is ahead of ppo on >= 3 of the 4 pairs, behind on none, within half of "
        "ppo's steps; then issue 64's goal (AUC ahead on >= 3 after Holm, final behind ppo "
        "or ppo+ppo-aa on none, at the paper's budget) and by how much on each pair. A "
        "pair may come from several protocol DIRs of one budget; METHOD=DIR takes only "
        "METHOD's runs from DIR.",
    )
    p.add_argument("dirs", nargs="+", metavar="DIR", help="protocol outputs, or METHOD=DIR")
    p.add_argument("--method", required=True, help="the transfer method judged (pved list)")
    p.add_argument("--out", type=Path, help="also write scoreboard.json/md here (atomically)")
    p.set_defaults(func=_cmd_scoreboard)


def _cmd_publish(args: argparse.Namespace) -> None:
    from pved.analysis.publish import publish
    from pved.errors import PvedError

    if not (args.root / "docs" / "protocol").is_dir():
        raise PvedError(f"--root {args.root}: no docs/protocol/ (want the repository's root)")
    changed = publish(args.root, check=args.check)
    if args.check and changed:
        stale = ", ".join(changed)
        raise PvedError(f"tables differ from their records in {stale}: run pved publish")
    verb = "would change" if args.check else "changed"
    print(f"{len(changed)} page(s) {verb}" + (f": {', '.join(changed)}" if changed else ""))


def add_publish(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser(
        "publish",
        help="regenerate the tables of results in README.md and docs/ from the records",
        description="Every table between <!-- pved:table NAME --> and <!-- /pved:table --> in "
        "README.md, docs/results.md and docs/results/<pair>.md, made anew from the committed "
        "records (docs/protocol/*/summary.json and the runs' records there), with one "
        "interval method: the two-level bootstrap over source policies and seeds. --check "
        "writes nothing and fails if a page differs from its records.",
    )
    p.add_argument("--root", type=Path, default=Path("."), help="repository root (default: .)")
    p.add_argument("--check", action="store_true", help="only say whether any page is stale")
    p.set_defaults(func=_cmd_publish)


def _cmd_analyze(args: argparse.Namespace) -> None:
    from pved.errors import PvedError

    if args.analysis == "subspaces":
        from pved.diagnostics.subspaces import subspaces_report

        subspaces_report(args.protocol, args.pair, episodes=args.episodes, videos=args.videos)
        print(args.protocol / "subspaces")
        return
    if args.analysis == "shaping-scale":
        from pved.diagnostics.shaping_scale import protocol_shaping_scale

        tables = protocol_shaping_scale(args.protocol, rows=args.rows, seed=args.seed)[1]
        out = args.protocol / "subspaces" / "shaping_scale.json"
    elif args.analysis == "source-reading":
        from pved.analysis.source_reading import protocol_source_reading

        tables = protocol_source_reading(args.protocol)[1]
        out = args.protocol / "subspaces" / "source_reading.json"
    elif args.analysis == "peg-success":
        from pved.diagnostics.peg_success import peg_success

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
        from pved.diagnostics.pairing_signal import compare_datasets, protocol_pairing_signal

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


def add_analyze(v: Verbs) -> None:
    sub = v.sub

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


VERBS = (
    add_report,
    add_tsne,
    add_bound,
    add_prior_policy,
    add_power,
    add_audit_shaping,
    add_audit_likelihood,
    add_video,
    add_compare,
    add_scoreboard,
    add_publish,
    add_analyze,
)
