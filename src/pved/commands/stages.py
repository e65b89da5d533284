"""The pipeline's verbs: one per stage of :mod:`pved.experiments.stages`, and ``pair``.

Each verb is a handler (``_cmd_<verb>``: the stage it calls, with the parsed options)
and beside it the function that adds its parser (``add_<verb>``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from pved.commands import Verbs, print_json

if TYPE_CHECKING:
    from pved.pair import Pair


def _pair(args: argparse.Namespace) -> Pair:
    """The door: ``--pair`` (a name or a spec file) resolved once, its runs under
    ``--runs``; the stage is handed this object and looks nothing up again."""
    from pved.pair import resolve_pair

    return resolve_pair(args.pair, args.runs)


def _cmd_list(args: argparse.Namespace) -> None:
    from pved.envs.registry import registered_env_ids
    from pved.models import MODELS
    from pved.spec import PRESETS
    from pved.transfer.methods import METHODS

    print("pairs:  " + ", ".join(sorted(PRESETS)))
    print("models: " + ", ".join(sorted(MODELS)))
    print("transfer methods:")
    for method in METHODS.values():
        print(f"  {method.name:<17} {method.summary}")
    print("envs:   " + ", ".join(registered_env_ids()))


def add_list(v: Verbs) -> None:
    sub = v.sub

    p = sub.add_parser("list", help="list the pairs, models and environments")
    p.set_defaults(func=_cmd_list)


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


def add_train_policy(v: Verbs) -> None:
    from pved.envs.registry import AGENTS, TASKS

    add, add_checkpoint_seconds = v.add, v.add_checkpoint_seconds

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


def _cmd_collect_pairs(args: argparse.Namespace) -> None:
    from pved.experiments.stages import collect_pairs

    print(
        collect_pairs(
            _pair(args),
            source_policy=args.source_policy,
            target_policy=args.target_policy,
            episodes=args.episodes,
            seed=args.seed,
            align=args.align,
            task=args.task,
            source_dataset=args.source_dataset,
        )
    )


def add_collect_pairs(v: Verbs) -> None:
    from pved.pairing.align import ALIGNMENTS

    add, pair_help, pair_tasks = v.add, v.pair_help, v.pair_tasks

    p = add("collect-pairs", "paired rollouts of both agents on the training task")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--source-policy",
        type=Path,
        help="policy.pt, an SB3 .zip, or a run directory (default: the pair spec's; shipped "
        "with pved for the built-in pairs)",
    )
    p.add_argument(
        "--source-dataset",
        help="instead of a source policy: a Minari dataset id or folder of the source's "
        "recorded episodes; the target is reset to each one's task (docs/sources.md)",
    )
    p.add_argument(
        "--target-policy",
        type=Path,
        help="policy.pt or its run directory (default: the pair spec's; shipped with pved for "
        "the built-in pairs)",
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


def _cmd_train_model(args: argparse.Namespace) -> None:
    from pved.experiments.stages import train_model

    print(
        train_model(
            _pair(args),
            args.model,
            dataset=args.dataset,
            seed=args.seed,
            epochs=args.epochs,
        )
    )


def add_train_model(v: Verbs) -> None:
    add, pair_help, models = v.add, v.pair_help, v.models

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


def _cmd_build_bank(args: argparse.Namespace) -> None:
    from pved.experiments.stages import build_bank

    print(
        build_bank(
            _pair(args),
            source_policy=args.source_policy,
            episodes=args.episodes,
            seed=args.seed,
            source_dataset=args.source_dataset,
        )
    )


def add_build_bank(v: Verbs) -> None:
    add, pair_help = v.add, v.pair_help

    p = add("build-bank", "roll out the source's target-task policy for the shaping term")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--source-policy",
        type=Path,
        help="policy.pt, an SB3 .zip, or a run directory (default: the pair spec's; shipped "
        "with pved for the built-in pairs)",
    )
    p.add_argument(
        "--source-dataset",
        help="instead of a source policy: a Minari dataset id or folder of the source's "
        "recorded target-task episodes (docs/sources.md)",
    )
    p.add_argument("--episodes", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_build_bank)


def _cmd_export_minari(args: argparse.Namespace) -> None:
    from pved.experiments.sources import export_source_dataset

    print(
        export_source_dataset(
            _pair(args),
            args.dataset_id,
            task=args.task,
            source_policy=args.source_policy,
            episodes=args.episodes,
            seed=args.seed,
        )
    )


def add_export_minari(v: Verbs) -> None:
    text = "write the source's rollouts as a Minari dataset (under MINARI_DATASETS_PATH)"
    p = v.add("export-minari", text)
    p.add_argument("dataset_id", help="the new dataset's id, e.g. reacher3-push-v0")
    p.add_argument("--pair", default="reacher", help=v.pair_help)
    p.add_argument(
        "--task", help="the source's task (default: the pair's target task, a bank's source)"
    )
    p.add_argument(
        "--source-policy",
        type=Path,
        help="policy.pt or an SB3 .zip (default: the pair spec's: shipped, the file it names, "
        "or the pair's own train-policy run under --runs)",
    )
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_export_minari)


def _cmd_transfer(args: argparse.Namespace) -> None:
    from pved.experiments.stages import transfer

    print_json(
        transfer(
            _pair(args),
            args.model,
            seed=args.seed,
            model_path=args.model_path,
            bank_path=args.bank,
            steps=args.steps,
            beta=args.beta,
            eval_every=args.eval_every,
            eval_episodes=args.eval_episodes,
            final_eval_episodes=args.final_eval_episodes,
            shaping_start=args.shaping_start,
            shaping_form=args.shaping_form,
            shaping_action=args.shaping_action,
            checkpoint_every_s=args.checkpoint_seconds,
        )
    )


def add_transfer(v: Verbs) -> None:
    add, add_checkpoint_seconds, pair_help, methods = (
        v.add,
        v.add_checkpoint_seconds,
        v.pair_help,
        v.methods,
    )

    p = add("transfer", "PPO of the target agent with the Eq. 10 shaping (or --model ppo)")
    p.add_argument("--pair", default="reacher", help=pair_help)
    p.add_argument(
        "--model",
        default="pved",
        help=f"{methods}: a method (`pved list` says what each is); default: %(default)s",
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
        metavar="FORM",
        help="how the distance D enters the reward (default: the method's): eq10, the "
        "paper's -beta*D; log1p: -beta*log(1+D), which keeps the term's ordering but "
        "compresses its range; potential: -beta*D as a look-back potential; align, prior: no "
        "reward term but a loss on the policy's mean action (pved-align's, pved-prior's) "
        "(all but eq10 beyond the paper)",
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


def _cmd_evaluate(args: argparse.Namespace) -> None:
    from pved.experiments.stages import evaluate

    print_json(
        evaluate(
            args.policy,
            args.env,
            episodes=args.episodes,
            seed=args.seed,
            reward=args.reward,
            pair=args.pair,
        )
    )


def add_evaluate(v: Verbs) -> None:
    sub = v.sub

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


def _cmd_pair(args: argparse.Namespace) -> None:
    from pved.spec import dump_pair, load_pair

    if args.action == "show":
        print(dump_pair(load_pair(args.spec)), end="")
    elif args.action == "signal":
        from pved.diagnostics.pairing_signal import format_signal, pair_signal

        print(
            format_signal(
                pair_signal(
                    args.spec,
                    episodes=args.episodes,
                    rows=args.rows,
                    seed=args.seed,
                    runs_root=args.runs,
                )
            )
        )
    else:
        from pved.experiments.pair_check import check_pair

        print(check_pair(args.spec, args.runs))


def add_pair(v: Verbs) -> None:
    pairs, sub = v.pairs, v.sub

    p = sub.add_parser("pair", help="show, check or ask the signal of a pair spec (docs/pairs.md)")
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
    a = actions.add_parser(
        "signal",
        help="does the pairing relate the agents? collect a few paired episodes and print the "
        "held-out ridge R² of one agent's step from its partner's, beside its shuffled floor",
    )
    a.add_argument("spec", help=f"a spec file, or {pairs}")
    a.add_argument("--episodes", type=int, default=100, help="default: %(default)s")
    a.add_argument("--rows", type=int, default=20_000, help="rows sampled (default: %(default)s)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument(
        "--runs",
        type=Path,
        default=Path("runs"),
        help="runs root: the pair's trained policies are looked for, and the paired episodes "
        "kept (and reused when asked again), there (default: %(default)s)",
    )
    p.set_defaults(func=_cmd_pair)


VERBS = (
    add_list,
    add_train_policy,
    add_collect_pairs,
    add_train_model,
    add_build_bank,
    add_export_minari,
    add_transfer,
    add_evaluate,
    add_pair,
)
