"""Bad input never costs a traceback or a run; a kill loses little work (issue 54).

One test per class of failure the issue found: values accepted that are wrong (a
negative or NaN β, zero epochs), tracebacks instead of one line (episode counts, a
directory that cannot be written), work lost to late checks (a bad final-evaluation
count, a refused command's ``config.json``), foreign inputs (a model or bank of another
pair) and a kill before the first checkpoint by steps. ``test_bad_input_properties.py``
drives the same checks with generated values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import Interrupt, params_of, run_cli
from pved.errors import PvedError
from pved.experiments import stages
from pved.experiments.stages import build_bank, collect_pairs, train_model, transfer
from pved.models import load_model, save_model
from pved.pretrained import pretrained_policy_path
from pved.rl.policy import load_policy
from pved.runs import Run
from pved.transfer.shaping import LatentShaping
from pved.transfer.source_bank import load_bank, save_bank

# one update of 16 x 128 steps, one evaluation episode: quick wherever a check comes late
TINY = ["--steps", "2048", "--eval-every", "0", "--eval-episodes", "1",
        "--final-eval-episodes", "1"]  # fmt: skip
# a policy file with nothing to do with the check under test (no Reacher4 Push one ships)
POLICY = pretrained_policy_path("Reacher3", "Push")


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A reacher dataset, model and bank made by the stages on a tiny budget."""
    runs = tmp_path_factory.mktemp("made")
    return {
        "dataset": collect_pairs("reacher", episodes=4, runs_root=runs, progress=False),
        "model": train_model("reacher", epochs=1, runs_root=runs, progress=False),
        "bank": build_bank("reacher", episodes=4, runs_root=runs),
    }


def refused(capsys: pytest.CaptureFixture[str], *argv: object, match: str) -> None:
    """``pved ARGV`` exits with 2 and one ``pved: error:`` line holding ``match``."""
    code, _, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("pved: error:"), err
    assert match in lines[0], lines[0]


def files_under(path: Path) -> list[Path]:
    return sorted(p for p in path.rglob("*")) if path.exists() else []


# -- values accepted that are wrong ---------------------------------------------------


@pytest.mark.parametrize("beta", ["-0.1", "nan", "inf", "-inf"])
@pytest.mark.parametrize("method", ["ppo", "pved"])
def test_a_negative_nan_or_infinite_beta_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], method: str, beta: str
) -> None:
    runs = tmp_path / "runs"
    refused(capsys, "transfer", "--runs", runs, "--model", method, f"--beta={beta}", *TINY,
            match=f"--beta must be a finite number >= 0, got {float(beta)!r}")  # fmt: skip
    assert not runs.exists()
    # beta = 0 is Eq. 10 without its term: a setting, not a mistake
    model, bank = tmp_path / "model.pt", tmp_path / "bank.npz"
    model.write_bytes(b"m")
    bank.write_bytes(b"b")
    spec = stages.transfer_spec("reacher", model_path=model, bank_path=bank, beta=0.0)
    assert spec.beta == 0.0


@pytest.mark.parametrize("beta", [-0.1, float("nan"), float("inf")])
def test_the_shaping_itself_refuses_a_beta_transfer_would_refuse(
    made: dict[str, Path], beta: float
) -> None:
    # what a notebook or a Stable-Baselines3 user builds directly
    model, bank = load_model(made["model"]), load_bank(made["bank"])
    indices = model.metadata["robot_state_indices_target"]
    with pytest.raises(PvedError, match="beta must be a finite number >= 0"):
        LatentShaping(model, bank, beta, indices)
    assert LatentShaping(model, bank, 0, indices).beta == 0.0


def test_zero_epochs_is_refused_before_a_model_is_written(
    made: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    for epochs in ("0", "-3"):
        refused(capsys, "train-model", "--runs", runs, "--dataset", made["dataset"],
                f"--epochs={epochs}",
                match=f"--epochs must be an integer >= 1, got {epochs}")  # fmt: skip
    assert not runs.exists()


# -- tracebacks instead of one line -----------------------------------------------------


@pytest.mark.parametrize("verb", ["collect-pairs", "build-bank"])
@pytest.mark.parametrize("episodes", ["0", "-1"])
def test_episode_counts_below_one_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: str, episodes: str
) -> None:
    runs = tmp_path / "runs"
    refused(capsys, verb, "--runs", runs, f"--episodes={episodes}",
            match=f"--episodes must be an integer >= 1, got {episodes}")  # fmt: skip
    assert not runs.exists()


def _no_work(what: str) -> Any:
    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError(f"{what} ran before the output was checked")

    return fail


@pytest.mark.parametrize(
    ("argv", "work", "option"),
    [
        (["train-policy", "--agent", "Reacher4", "--task", "Push", "--runs", "{x}"],
         "pved.experiments.stages.train_ppo", "--runs"),
        (["collect-pairs", "--runs", "{x}"],
         "pved.experiments.stages.collect_episode_pairs", "--runs"),
        (["train-model", "--runs", "{x}", "--dataset", "{dataset}"],
         "pved.experiments.stages.fit_model", "--runs"),
        (["build-bank", "--runs", "{x}"], "pved.experiments.stages.build_source_bank", "--runs"),
        (["transfer", "--model", "ppo", "--runs", "{x}"],
         "pved.experiments.stages.train_ppo", "--runs"),
        (["transfer", "--runs", "{x}", "--model-path", "{model}", "--bank", "{bank}"],
         "pved.experiments.stages.train_ppo", "--runs"),
        (["video", "--policy", str(POLICY), "--env", "pved/Reacher3Push-v0",
          "--out", "{x}/v.gif"], "pved.diagnostics.video._rollout_frames", "--out"),
        (["tsne", "--model", "{model}", "--target-policy", str(POLICY), "--out", "{x}"],
         "pved.diagnostics.transferred.embed_rollouts", "--out"),
        (["audit-shaping", "--model", "{model}", "--bank", "{bank}", "--out", "{x}/a.json"],
         "pved.diagnostics.shaping_audit.audit_transfer_start", "--out"),
        (["audit-likelihood", "--dataset", "{dataset}", "--runs", "{x}"],
         "pved.models.train.train_model", "--runs"),
        (["audit-likelihood", "--dataset", "{dataset}", "--runs", "{tmp}/r", "--out", "{x}/l.json"],
         "pved.models.train.train_model", "--out"),
        (["compare", "--a", "{tmp}", "--b", "{tmp}", "--json", "{x}/c.json"],
         "pved.analysis.compare.compare_runs", "--json"),
        (["claims", "{tmp}", "--out", "{x}"], "pved.analysis.claims.judge_claims", "--out"),
        (["plot", "{tmp}/none", "--out", "{x}/p.png"], None, "--out"),
        (["plot", "{x}"], None, "DIR"),
        (["protocol", "--pair", "reacher", "--out", "{x}", "--backend", "processes"],
         "pved.protocol.driver.run_jobs", "--out"),
        (["demo", "--runs", "{x}"], "pved.experiments.demo.collect_pairs", "--runs"),
        (["demo", "--runs", "{tmp}/d", "--out", "{x}"],
         "pved.experiments.demo.collect_pairs", "--out"),
        (["batch", "export", "--protocol", "{tmp}", "--batch", "{x}"],
         "pved.protocol.driver.ProtocolPlan.load", "--batch"),
        (["batch", "run", "--batch", "{tmp}", "--pack", "{x}"],
         "pved.protocol.batch.run_batch", "--pack"),
    ],
    ids=lambda v: v[0] if isinstance(v, list) else None,
)  # fmt: skip
def test_a_directory_that_cannot_be_written_is_found_before_the_work(
    made: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    work: str | None,
    option: str,
) -> None:
    # a path under a regular file: no one can make it, root included (tests run as root
    # here, and root ignores permission bits)
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    if work is not None:
        monkeypatch.setattr(work, _no_work(work))
    paths = {"x": blocker / "sub", "tmp": tmp_path, **{k: str(v) for k, v in made.items()}}
    refused(capsys, *(a.format(**paths) for a in argv), match=f"{option} {blocker / 'sub'}")
    assert files_under(tmp_path) == [blocker]


# -- work lost to late checks -----------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["transfer", "--model", "ppo", "--final-eval-episodes", "-1"],
         "--final-eval-episodes must be an integer >= 1, got -1"),
        (["transfer", "--model", "ppo", "--final-eval-episodes", "0"],
         "--final-eval-episodes must be an integer >= 1, got 0"),
        (["transfer", "--model", "ppo", "--eval-episodes", "0"],
         "--eval-episodes must be an integer >= 1, got 0"),
        (["transfer", "--model", "ppo", "--eval-every=-2048"],
         "--eval-every must be an integer >= 0, got -2048"),
        (["transfer", "--model", "ppo", "--seed=-1"],
         "--seed must be an integer in [0, 4294967295], got -1"),
        (["transfer", "--model", "ppo", "--checkpoint-seconds=nan"],
         "--checkpoint-seconds must be a number >= 0, got nan"),
        (["transfer", "--shaping-start=-5"], "--shaping-start must be an integer >= 0, got -5"),
        (["train-policy", "--agent", "Reacher4", "--task", "Push", "--eval-episodes", "0"],
         "--eval-episodes must be an integer >= 1, got 0"),
        (["train-policy", "--agent", "Reacher4", "--task", "Push", "--seed=-1"],
         "--seed must be an integer in [0, 4294967295], got -1"),
        (["train-policy", "--agent", "Reacher4", "--task", "Push", "--reward", "nope"],
         "unknown reward 'nope'"),
    ],
)  # fmt: skip
def test_a_refusal_comes_before_the_training_and_leaves_no_run_directory(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    match: str,
) -> None:
    monkeypatch.setattr(stages, "train_ppo", _no_work("training"))
    runs = tmp_path / "runs"
    refused(capsys, *argv, "--runs", runs, match=match)
    assert not runs.exists()  # no config.json, no policy.pt without result.json


# -- foreign inputs -----------------------------------------------------------------------


def test_a_model_or_bank_of_another_pair_is_refused_and_old_files_are_taken(
    made: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model, bank = load_model(made["model"]), load_bank(made["bank"])
    meta = dict(model.metadata)

    def model_with(path: Path, **changes: Any) -> Path:
        model.metadata = {k: v for k, v in {**meta, **changes}.items() if v is not None}
        return save_model(model, path)

    def bank_with(path: Path, **changes: Any) -> Path:
        header = {k: v for k, v in {**bank.header, **changes}.items() if v is not None}
        return save_bank(path, type(bank)(bank.x, bank.lengths, bank.keys, header))

    runs = tmp_path / "runs"
    foreign = [
        (model_with(tmp_path / "m1.pt", pair="jaco-fetch"), made["bank"],
         "its pair is 'jaco-fetch', reacher's is 'reacher'"),
        (model_with(tmp_path / "m2.pt", pair=None, source_agent="Jaco"), made["bank"],
         "its source_agent is 'Jaco', reacher's is 'Reacher3'"),
        (model_with(tmp_path / "m3.pt", robot_state_indices_target=[0, 1, 2]), made["bank"],
         "reads the target's robot state at [0, 1, 2]"),
        (made["model"], bank_with(tmp_path / "b1.npz", env_id="pved/Reacher3Reach-v0"),
         "was made on pved/Reacher3Reach-v0, reacher's is pved/Reacher3Push-v0"),
        (made["model"], bank_with(tmp_path / "b2.npz", match_keys=["target"]),
         "matches on ['target'], reacher on ['button_start']"),
    ]  # fmt: skip
    for model_path, bank_path, match in foreign:
        refused(capsys, "transfer", "--runs", runs, "--model-path", model_path,
                "--bank", bank_path, *TINY, match=match)  # fmt: skip
        assert not runs.exists(), match
    # the analysis verbs take the same check
    refused(capsys, "bound", "--model", foreign[0][0], "--target-policy", POLICY,
            "--episodes", "1", match="its pair is 'jaco-fetch'")  # fmt: skip
    refused(capsys, "audit-shaping", "--model", made["model"], "--bank", foreign[3][1],
            "--steps", "64", match="was made on pved/Reacher3Reach-v0")  # fmt: skip
    # a model and a bank written before these keys existed are taken as they are
    old_model = model_with(tmp_path / "old.pt", pair=None, source_agent=None,
                           robot_state_indices_source=None,
                           robot_state_indices_target=None)  # fmt: skip
    old_bank = bank_with(tmp_path / "old.npz", env_id=None, match_keys=None,
                         robot_state_indices=None)  # fmt: skip
    code, _, err = run_cli(capsys, "transfer", "--runs", runs, "--model-path", old_model,
                             "--bank", old_bank, *TINY)  # fmt: skip
    assert code == 0, err


# -- a kill before the first checkpoint by steps ----------------------------------------------


def test_a_transfer_killed_before_its_first_step_checkpoint_resumes_and_ends_as_one_run(
    made: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    per_update = 16 * 128  # the reacher transfer's PPO: 16 copies x 128 steps
    options: dict[str, Any] = {
        "model_path": made["model"],
        "bank_path": made["bank"],
        "steps": 4 * per_update,
        "eval_every": per_update,
        "eval_episodes": 1,
        "final_eval_episodes": 2,
        "progress": False,
    }
    straight = transfer("reacher", runs_root=tmp_path / "a", checkpoint_every_s=None, **options)

    # every evaluation's step is seen; the run is killed at the one after update 2, before
    # that update's checkpoint and long before the first by steps (every 100k)
    seen: list[int] = []
    kill_at: list[int] = [2 * per_update]
    make_eval = stages._eval_fn

    def recording_eval_fn(*args: Any, **kwargs: Any) -> Any:
        evaluate = make_eval(*args, **kwargs)

        def watched(policy: Any, env_steps: int) -> dict[str, float]:
            seen.append(env_steps)
            if env_steps in kill_at:
                raise Interrupt
            return evaluate(policy, env_steps)

        return watched

    monkeypatch.setattr(stages, "_eval_fn", recording_eval_fn)
    # every update checkpoints by time: a clock of 0 s, as a minute is in a long run
    with pytest.raises(Interrupt):
        transfer("reacher", runs_root=tmp_path / "b", checkpoint_every_s=0, **options)
    run_dir = tmp_path / "b/reacher/transfer/pved/seed20000"
    state = Run(run_dir, {}).latest_checkpoint()
    assert state is not None and state["global_step"] == per_update
    assert state["config"]["checkpoint_every"] > 4 * per_update  # none of them by steps
    assert not (run_dir / "result.json").exists()

    seen.clear()
    kill_at.clear()
    resumed = transfer("reacher", runs_root=tmp_path / "b", checkpoint_every_s=0, **options)
    # it went on from the checkpoint: no evaluation at step 0 or 1 update again
    assert seen == [2 * per_update, 3 * per_update, 4 * per_update]
    # and ends where the uninterrupted run ends, to the last bit
    finals = {k: v for k, v in straight.items() if k.startswith("final/")}
    assert finals == {k: v for k, v in resumed.items() if k.startswith("final/")}
    policy_a = load_policy(tmp_path / "a/reacher/transfer/pved/seed20000/policy.pt")
    policy_b = load_policy(run_dir / "policy.pt")
    assert np.array_equal(params_of(policy_a), params_of(policy_b))
    updates = [r["step"] for r in Run(run_dir, {}).read_metrics() if "loss/approx_kl" in r]
    assert updates == [k * per_update for k in range(1, 5)]  # each update logged once
