"""The whole Reacher pipeline through the ``pved`` CLI on a tiny budget, and its bad inputs.

Each stage runs as a user would run it (``pved <verb> ...``) in a temporary runs root,
from the shipped pretrained policies to a report folder.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from helpers import params_of, run_cli
from pved.cli import main
from pved.models import MODELS, load_model
from pved.pairing.dataset import load_dataset, save_dataset
from pved.pretrained import pretrained_policy_path
from pved.rl.guide import GUIDE_GRAD_RATIO
from pved.rl.policy import load_policy

TINY_TRANSFER = ["--steps", "4096", "--eval-every", "2048", "--eval-episodes", "16",
                 "--final-eval-episodes", "16"]  # fmt: skip


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Runs every stage once (module scope: the tests below read what it wrote)."""
    runs = tmp_path_factory.mktemp("runs")
    assert main(["collect-pairs", "--runs", str(runs), "--episodes", "32"]) == 0
    assert main(["train-model", "--runs", str(runs), "--epochs", "2"]) == 0
    assert main(["build-bank", "--runs", str(runs), "--episodes", "16"]) == 0
    for method in ("pved", "ppo", "oracle"):
        assert main(["transfer", "--runs", str(runs), "--model", method, *TINY_TRANSFER]) == 0
    return runs


def test_model_result_says_whether_the_shared_subspace_collapsed(pipeline: Path) -> None:
    from pved.models.train import shared_subspace_collapsed

    result = json.loads((pipeline / "reacher/model/pved/seed0/result.json").read_text())
    val = {k.removeprefix("val/"): v for k, v in result.items() if k.startswith("val/")}
    assert "kl_SS" in val and result["shared_collapsed"] is shared_subspace_collapsed(val)


def test_every_stage_writes_its_run_directory(pipeline: Path) -> None:
    root = pipeline / "reacher"
    for stage in (
        "pairs/subsample/seed0",
        "model/pved/seed0",
        "bank/Reacher3-Push/seed0",
        "transfer/pved/seed20000",
        "transfer/ppo/seed20000",
        "transfer/oracle/seed20000",
    ):
        run = root / stage
        assert (run / "config.json").exists(), stage
        result = json.loads((run / "result.json").read_text())
        assert "config_hash" in result
    data = load_dataset(root / "pairs/subsample/seed0/pairs.npz")
    assert len(np.unique(data.episode)) == 32
    # both agents solved the same task instance in every paired episode
    assert set(data.header["shared_task_keys"]) == {"target"}
    # transfer runs log a learning curve with TensorBoard events beside it
    for method in ("pved", "ppo"):
        run = root / "transfer" / method / "seed20000"
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        assert [r["step"] for r in rows if "eval/success_rate" in r] == [0, 2048, 4096]
        assert any(p.name.startswith("events.out.tfevents") for p in run.iterdir())
        result = json.loads((run / "result.json").read_text())
        assert result["final/episodes"] == 16
    shaped = [
        json.loads(line)
        for line in (root / "transfer/pved/seed20000/metrics.jsonl").read_text().splitlines()
    ]
    assert any("rollout/reward_shaping" in r for r in shaped)


def test_done_stage_is_skipped(pipeline: Path, capsys: pytest.CaptureFixture[str]) -> None:
    result = pipeline / "reacher/transfer/ppo/seed20000/result.json"
    before = result.stat().st_mtime_ns
    code, out, _ = run_cli(capsys, "transfer", "--runs", pipeline, "--model", "ppo",
                           *TINY_TRANSFER)  # fmt: skip
    assert code == 0 and json.loads(out)["method"] == "ppo"
    assert result.stat().st_mtime_ns == before


def test_report_and_evaluate(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_dir = tmp_path / "report"
    code, out, _ = run_cli(capsys, "report", "--runs", pipeline, "--seeds", "20000",
                           "--out", out_dir)  # fmt: skip
    assert code == 0
    for name in ("curves_success_rate.png", "curves_return.png", "results.md", "results.json"):
        assert (out_dir / name).stat().st_size > 0
    policy = pipeline / "reacher/transfer/pved/seed20000/policy.pt"
    code, out, _ = run_cli(capsys, "evaluate", "--policy", policy, "--env",
                           "pved/Reacher4Push-v0", "--episodes", "16")  # fmt: skip
    assert code == 0 and json.loads(out)["episodes"] == 16
    # its run directory stands for it
    code, by_dir, _ = run_cli(capsys, "evaluate", "--policy", policy.parent, "--env",
                              "pved/Reacher4Push-v0", "--episodes", "16")  # fmt: skip
    assert code == 0 and json.loads(by_dir) == json.loads(out)


def one_line_error(capsys: pytest.CaptureFixture[str], *argv: object, match: str) -> None:
    code, _, err = run_cli(capsys, *map(str, argv))
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pved: error:"), err
    assert match in lines[0], lines[0]


@pytest.mark.parametrize(
    ("verb", "option"),
    [("transfer", "--model"), ("train-model", "--model"), ("collect-pairs", "--align"),
     ("train-policy", "--agent"), ("train-policy", "--task"), ("protocol", "--pair")],
)  # fmt: skip
def test_help_names_the_values_a_choice_takes(
    verb: str, option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # the names come from the registries that check them, so --help and the one-line
    # error for a wrong name (test_bad_input_is_one_line_and_nonzero) list the same ones
    from pved.envs.registry import AGENTS, TASKS
    from pved.pairing.align import ALIGNMENTS
    from pved.spec import PRESETS

    with pytest.raises(SystemExit) as exit_info:
        main([verb, "--help"])
    assert exit_info.value.code == 0
    text = "".join(capsys.readouterr().out.split())  # argparse wraps lines anywhere
    names = {
        "--model": [*MODELS, *(["ppo", "oracle"] if verb == "transfer" else [])],
        "--align": ALIGNMENTS,
        "--agent": AGENTS,
        "--task": TASKS,
        "--pair": PRESETS,
    }[option]
    assert all(name in text for name in names), text
    if verb != "train-policy":  # the one verb here that takes no pair
        assert all(pair in text for pair in PRESETS)


def test_bad_input_is_one_line_and_nonzero(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--pair", "nope",
                   match="unknown pair 'nope'")  # fmt: skip
    one_line_error(capsys, "train-policy", "--runs", runs, "--agent", "Robot9", "--task",
                   "Reach", match="unknown agent 'Robot9'")  # fmt: skip
    one_line_error(capsys, "train-policy", "--runs", runs, "--agent", "Reacher3", "--task",
                   "Fly", match="unknown task 'Fly'")  # fmt: skip
    one_line_error(capsys, "train-model", "--runs", runs, "--model", "magic",
                   "--dataset", pipeline / "reacher/pairs/subsample/seed0/pairs.npz",
                   match="magic")  # fmt: skip
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"\x00garbage")
    one_line_error(capsys, "train-model", "--runs", runs, "--dataset", corrupt,
                   match=str(corrupt))  # fmt: skip
    # a dataset whose dims do not match the pair's agents (source and target swapped)
    data = load_dataset(pipeline / "reacher/pairs/subsample/seed0/pairs.npz")
    swapped = type(data)(
        obs_source=data.obs_target, act_source=data.act_target,
        obs_target=data.obs_source, act_target=data.act_source,
        episode=data.episode, t_source=data.t_target, t_target=data.t_source,
        task=data.task,
        header={**data.header,
                **{f"{k}_source": data.header[f"{k}_target"] for k in ("obs_dim", "act_dim")},
                **{f"{k}_target": data.header[f"{k}_source"] for k in ("obs_dim", "act_dim")},
                "robot_state_indices_source": data.header["robot_state_indices_target"],
                "robot_state_indices_target": data.header["robot_state_indices_source"]},
    )  # fmt: skip
    save_dataset(tmp_path / "swapped.npz", swapped)
    one_line_error(capsys, "train-model", "--runs", runs, "--dataset", tmp_path / "swapped.npz",
                   match="dataset obs_source has dim 18, but the agent's is 15")  # fmt: skip
    one_line_error(capsys, "evaluate", "--policy", pretrained_policy_path("Reacher3", "Reach"),
                   "--env", "pved/Reacher4Push-v0", match="do not match")  # fmt: skip
    one_line_error(capsys, "evaluate", "--policy", corrupt, "--env", "pved/Reacher4Push-v0",
                   match=str(corrupt))  # fmt: skip
    one_line_error(capsys, "transfer", "--runs", runs, "--model", "pved",
                   match="not found")  # fmt: skip
    one_line_error(capsys, "transfer", "--runs", runs, "--model", "magic",
                   match="unknown method 'magic'")  # fmt: skip
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--align", "warp",
                   match="--align must be one of subsample, time, dtw, phase")  # fmt: skip
    # an input file that is not there, or a directory that is no run of its stage
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--source-policy",
                   tmp_path / "none.pt", match="Reacher3's policy not found")  # fmt: skip
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-policy", tmp_path,
                   match="a directory without policy.pt")  # fmt: skip
    one_line_error(capsys, "train-model", "--runs", runs, "--dataset", tmp_path,
                   match="dataset not found")  # fmt: skip
    one_line_error(capsys, "transfer", "--runs", runs, "--model", "pved", "--model-path",
                   tmp_path, match="model not found")  # fmt: skip
    one_line_error(capsys, "transfer", "--runs", runs, "--model", "pved", "--model-path",
                   pipeline / "reacher/model/pved/seed0", "--bank", tmp_path / "none.npz",
                   match="source bank not found")  # fmt: skip
    # nothing half-written: failed stages left no result.json behind
    assert not list(runs.rglob("result.json")) if runs.exists() else True


def _pved_transfer_by_run_dirs(
    capsys: pytest.CaptureFixture[str], pipeline: Path, runs: Path, *extra: object
) -> tuple[int, str, str]:
    """``pved transfer --model pved`` into ``runs`` on the pipeline's seed-0 model and
    bank, named by their run directories, on the tiny budget."""
    root = pipeline / "reacher"
    return run_cli(capsys, "transfer", "--runs", runs, "--model", "pved",
                   "--model-path", root / "model/pved/seed0",
                   "--bank", root / "bank/Reacher3-Push/seed0",
                   *extra, *TINY_TRANSFER)  # fmt: skip


def test_a_stage_takes_an_earlier_stage_by_its_run_directory(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the directory a stage printed stands for the file in it: the same inputs, by digest
    root = pipeline / "reacher"
    code, _, err = _pved_transfer_by_run_dirs(capsys, pipeline, tmp_path)
    assert code == 0, err
    by_dir = json.loads((tmp_path / "reacher/transfer/pved/seed20000/config.json").read_text())
    by_file = json.loads((root / "transfer/pved/seed20000/config.json").read_text())
    assert by_dir["config_hash"] == by_file["config_hash"]
    assert by_dir["config"]["model"] == by_file["config"]["model"]


def test_a_shaping_that_starts_after_the_last_step_is_plain_ppo(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --shaping-start holds the term at 0 (not in the paper); held for the whole run, the
    # shaped run is the PPO run of its seed: same rewards, same updates, same weights
    root = pipeline / "reacher"
    code, _, err = _pved_transfer_by_run_dirs(capsys, pipeline, tmp_path, "--shaping-start", 4096)
    assert code == 0, err
    run = tmp_path / "reacher/transfer/pved/seed20000"
    assert json.loads((run / "config.json").read_text())["config"]["shaping_start"] == 4096
    late = params_of(load_policy(run / "policy.pt"))
    assert np.array_equal(late, params_of(load_policy(root / "transfer/ppo/seed20000/policy.pt")))
    # the term from step 0 moves the weights
    shaped = params_of(load_policy(root / "transfer/pved/seed20000/policy.pt"))
    assert not np.array_equal(late, shaped)
    code, _, err = run_cli(capsys, "transfer", "--runs", tmp_path, "--model", "ppo",
                           "--shaping-start", 10, *TINY_TRANSFER)  # fmt: skip
    assert code != 0 and "has no shaping term" in err and len(err.strip().splitlines()) == 1


def test_the_log1p_shaping_form_trains_on_a_smaller_term(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --shaping-form log1p (not in the paper) shapes with −β·log(1 + D): the run records
    # it, and its rollouts' shaping term is smaller in size than Eq. 10's from step 0
    root = pipeline / "reacher"
    code, _, err = _pved_transfer_by_run_dirs(capsys, pipeline, tmp_path, "--shaping-form", "log1p")
    assert code == 0, err
    run = tmp_path / "reacher/transfer/pved/seed20000"
    assert json.loads((run / "config.json").read_text())["config"]["shaping_form"] == "log1p"

    def first_shaping(run_dir: Path) -> float:
        rows = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
        return float(
            next(r for r in rows if "rollout/reward_shaping" in r)["rollout/reward_shaping"]
        )

    eq10 = first_shaping(root / "transfer/pved/seed20000")
    logged = first_shaping(run)
    assert eq10 < logged < 0.0
    code, _, err = run_cli(capsys, "transfer", "--runs", tmp_path, "--model", "pved",
                           "--shaping-form", "cube", *TINY_TRANSFER)  # fmt: skip
    assert code != 0 and "unknown shaping form 'cube'" in err
    assert len(err.strip().splitlines()) == 1


def test_oracle_trains_on_the_full_reward_and_is_evaluated_on_the_default(
    pipeline: Path,
) -> None:
    run = pipeline / "reacher/transfer/oracle/seed20000"
    config = json.loads((run / "config.json").read_text())["config"]
    assert config["train_reward"] == "full" and "model" not in config
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    terms = [r for r in rows if "rollout/reward_ee_button" in r]
    assert terms, "the oracle's training reward has the source's ee->button term"
    ppo_rows = (pipeline / "reacher/transfer/ppo/seed20000/metrics.jsonl").read_text()
    assert "rollout/reward_ee_button" not in ppo_rows


def test_pairs_on_the_target_task(
    pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--task`` pairs the agents on the target task (an analysis option), with the
    parameters a bank is matched on shared, in a run of its own."""
    target_policy = pipeline / "reacher/transfer/ppo/seed20000"
    code, out, err = run_cli(capsys, "collect-pairs", "--runs", tmp_path, "--episodes", "8",
                             "--task", "Push", "--target-policy", target_policy)  # fmt: skip
    assert code == 0, err
    path = Path(out.strip())
    assert path.parent == tmp_path / "reacher/pairs/Push-subsample/seed0"
    data = load_dataset(path)
    assert data.header["source_env_id"] == "pved/Reacher3Push-v0"
    assert data.header["target_env_id"] == "pved/Reacher4Push-v0"
    assert list(data.task) == ["button_start"] and len(data.task["button_start"]) == 8
    config = json.loads((path.parent / "config.json").read_text())["config"]
    assert config["task"] == "Push"
    # the training task's runs record no task, so their hashes are those made before
    default = json.loads((pipeline / "reacher/pairs/subsample/seed0/config.json").read_text())
    assert "task" not in default["config"]
    # a model fits them, its dims checked against the envs they came from
    code, _, err = run_cli(capsys, "train-model", "--runs", tmp_path, "--dataset", path,
                           "--epochs", "1")  # fmt: skip
    assert code == 0, err
    one_line_error(capsys, "collect-pairs", "--runs", tmp_path, "--task", "Fly",
                   match="unknown task 'Fly' for reacher")  # fmt: skip
    # no target-task policy of the target agent is shipped: it must be given
    one_line_error(capsys, "collect-pairs", "--runs", tmp_path, "--task", "Push",
                   match="no pretrained policy for Reacher4 on Push")  # fmt: skip


def test_dtw_alignment_stage(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "collect-pairs", "--runs", tmp_path, "--episodes", "16",
                             "--align", "dtw")  # fmt: skip
    assert code == 0, err
    data = load_dataset(Path(out.strip()))
    assert data.header["alignment"] == "dtw" and len(data.header["dtw"]) == 2
    assert len(np.unique(data.episode)) == 16
    for e in range(16):
        rows = data.episode == e
        t_s, t_t = data.t_source[rows], data.t_target[rows]
        # a warping path: monotone, from both first steps to both last steps
        assert (t_s[0], t_t[0]) == (0, 0) and (t_s[-1], t_t[-1]) == (49, 49)
        assert np.all(np.diff(t_s) >= 0) and np.all(np.diff(t_t) >= 0)
    assert 0.0 <= data.header["dtw"][-1]["moved_fraction"] <= 1.0


def test_phase_alignment_stage(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "collect-pairs", "--runs", tmp_path, "--episodes", "8",
                             "--align", "phase")  # fmt: skip
    assert code == 0, err
    data = load_dataset(Path(out.strip()))
    phase = data.header["phase"]
    assert data.header["alignment"] == "phase" and phase["base"] in ("time", "subsample")
    assert 0 < phase["pc1_variance_source"] <= 1 and 0 < phase["pc1_variance_target"] <= 1
    assert 0 < phase["moved_fraction"] <= 1  # the two arms do not swing in step
    for e in range(8):
        rows = data.episode == e
        t_s, t_t = data.t_source[rows], data.t_target[rows]
        # the base pairing's target steps, each once; a source step near its time partner
        assert t_t.tolist() == list(range(50))
        assert np.abs(t_s - t_t).max() <= phase["window"]


@pytest.mark.parametrize("model", sorted(MODELS))
def test_every_model_trains_and_shapes_through_the_cli(
    pipeline: Path, tmp_path: Path, model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    root = pipeline / "reacher"
    dataset = root / "pairs/subsample/seed0/pairs.npz"
    bank = root / "bank/Reacher3-Push/seed0/bank.npz"
    code, out, err = run_cli(capsys, "train-model", "--runs", tmp_path, "--model", model,
                             "--dataset", dataset, "--epochs", "1")  # fmt: skip
    assert code == 0, err
    model_file = Path(out.strip())
    assert load_model(model_file).name == model
    code, out, err = run_cli(capsys, "transfer", "--runs", tmp_path, "--model", model,
                             "--model-path", model_file, "--bank", bank, "--steps", "2048",
                             "--eval-every", "2048", "--eval-episodes", "16",
                             "--final-eval-episodes", "16")  # fmt: skip
    assert code == 0, err
    run = tmp_path / "reacher/transfer" / model / "seed20000"
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    shaping = [r["rollout/reward_shaping"] for r in rows if "rollout/reward_shaping" in r]
    assert shaping and all(v < 0 for v in shaping)  # −β·distance, averaged over the rollout


def test_the_align_methods_guide_until_their_own_share_of_the_run(pipeline: Path) -> None:
    # spec -> LatentShaping -> AlignGuide -> PPO, through the CLI: with 4 updates (progress
    # 0, 1/4, 1/2, 3/4 before each) pved-align (guide gone at 1/2) guides the first two,
    # pved-align-short (gone at 1/4) only the first
    guided = {}
    for method in ("pved-align", "pved-align-short"):
        code = main(["transfer", "--runs", str(pipeline), "--model", method, "--steps", "8192",
                     "--eval-every", "8192", "--eval-episodes", "16",
                     "--final-eval-episodes", "16"])  # fmt: skip
        assert code == 0
        run = pipeline / "reacher/transfer" / method / "seed20000"
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        losses = [r["loss/guide_loss"] for r in rows if "loss/guide_loss" in r]
        assert len(losses) == 4, rows
        guided[method] = [loss > 0 for loss in losses]
        result = json.loads((run / "result.json").read_text())
        assert result["guide_backend"] == "numpy"
        # the D gate's limit read on the model's own pairs; the gates and the bound recorded
        assert result["guide_d_limit"] > 0
        assert [r["guide/gate_open"] for r in rows if "guide/gate_open" in r] == [1.0] * 4
        ratios = [r["loss/guide_grad_ratio"] for r in rows if "loss/guide_grad_ratio" in r]
        assert len(ratios) == 4 and max(ratios) <= GUIDE_GRAD_RATIO * (1 + 1e-6)
        assert all("loss/guide_d_masked" in r for r in rows if "loss/guide_loss" in r)
    assert guided == {
        "pved-align": [True, True, False, False],
        "pved-align-short": [True, False, False, False],
    }


def test_pved_anneal_pays_the_term_until_half_the_run(pipeline: Path) -> None:
    # spec -> LatentShaping(stop) -> PPO, through the CLI: 4 updates of 2048 rows; the
    # term's weight falls from 1 to 0 over the first two (stop: 4096 rows), 0 after
    code = main(["transfer", "--runs", str(pipeline), "--model", "pved-anneal", "--steps",
                 "8192", "--eval-every", "8192", "--eval-episodes", "16",
                 "--final-eval-episodes", "16"])  # fmt: skip
    assert code == 0
    run = pipeline / "reacher/transfer/pved-anneal/seed20000"
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    shaping = [r["rollout/reward_shaping"] for r in rows if "rollout/reward_shaping" in r]
    assert len(shaping) == 4 and shaping[0] < shaping[1] < 0.0 and shaping[2:] == [0.0, 0.0]
    assert json.loads((run / "config.json").read_text())["config"]["reward_anneal"] == 0.5


def test_transfer_evaluates_on_the_presets_schedule_by_default(tmp_path: Path) -> None:
    from pved.spec import get_preset

    code = main(["transfer", "--runs", str(tmp_path), "--model", "ppo", "--steps", "2048",
                 "--eval-episodes", "16", "--final-eval-episodes", "16"])  # fmt: skip
    assert code == 0
    config = json.loads((tmp_path / "reacher/transfer/ppo/seed20000/config.json").read_text())
    assert config["config"]["ppo"]["eval_every"] == get_preset("reacher").transfer.eval_every


@pytest.mark.parametrize("pair", ["walker-hopper", "humanoid-ant"])
def test_locomotion_curve_points_take_one_batched_pass(pair: str) -> None:
    # Paper IV.A's metric is the final score over 100 episodes; a curve point on 100
    # 1000-step episodes would cost twice the training between points (decisions.md).
    from pved.config import EVAL_NUM_ENVS
    from pved.spec import get_preset

    transfer = get_preset(pair).transfer
    assert transfer.final_eval_episodes == 100
    assert transfer.eval_episodes == EVAL_NUM_ENVS


@pytest.mark.parametrize(
    ("pair", "source", "target", "training", "target_task", "metric"),
    [
        ("walker-hopper", "Walker2d", "Hopper", "Slope", "Curve", "x_position_mean"),
        ("humanoid-ant", "Humanoid", "Ant", "Slope", "Curve", "x_position_mean"),
        ("jaco-fetch", "Jaco", "Fetch4", "Reach", "Peg", "success_rate"),
    ],
)
def test_pair_runs_through_the_pipeline_at_a_smoke_budget(
    pair: str,
    source: str,
    target: str,
    training: str,
    target_task: str,
    metric: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    runs = tmp_path / "runs"

    def policy(agent: str, task: str) -> Path:
        code, out, err = run_cli(capsys, "train-policy", "--runs", runs, "--agent", agent,
                                 "--task", task, "--steps", "2048",
                                 "--eval-episodes", "2")  # fmt: skip
        assert code == 0, err
        return Path(out.strip().splitlines()[-1])

    src_slope, tgt_slope, src_curve = (
        policy(source, training), policy(target, training), policy(source, target_task)
    )  # fmt: skip
    code, out, err = run_cli(capsys, "collect-pairs", "--runs", runs, "--pair", pair,
                             "--source-policy", src_slope, "--target-policy", tgt_slope,
                             "--episodes", "16")  # fmt: skip
    assert code == 0, err
    data = load_dataset(Path(out.strip()))
    assert len(np.unique(data.episode)) == 16
    if training == "Slope":  # both agents of a paired episode climbed one slope in [2, 10]°
        slopes = data.task["slope_deg"]
        assert slopes.shape[0] == 16 and np.all((slopes >= 2.0) & (slopes <= 10.0))
    if pair == "humanoid-ant":  # paired by physical time: 0.015 s vs 0.05 s steps
        assert data.header["alignment"] == "time"
        gap = np.abs(data.t_source * data.header["dt_source"] - data.t_target * 0.05)
        assert data.header["dt_target"] == pytest.approx(0.05) and gap.max() <= 0.0075 + 1e-9
    assert main(["train-model", "--runs", str(runs), "--pair", pair, "--epochs", "1"]) == 0
    code, _, err = run_cli(capsys, "build-bank", "--runs", runs, "--pair", pair,
                           "--source-policy", src_curve, "--episodes", "16")  # fmt: skip
    assert code == 0, err
    for method in ("pved", "ppo"):
        code, out, err = run_cli(capsys, "transfer", "--runs", runs, "--pair", pair, "--model",
                                 method, "--steps", "2048", "--eval-every", "2048",
                                 "--eval-episodes", "2", "--final-eval-episodes", "2")  # fmt: skip
        assert code == 0, err
        assert f"final/{metric}" in json.loads(out)
    code, _, err = run_cli(capsys, "report", "--runs", runs, "--pair", pair, "--seeds",
                           "20000", "--out", tmp_path / "report")  # fmt: skip
    assert code == 0, err
    assert metric in (tmp_path / "report/results.md").read_text()


def test_analysis_verbs(pipeline: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = pipeline / "reacher/model/pved/seed0"
    target = pipeline / "reacher/transfer/pved/seed20000"
    code, out, err = run_cli(capsys, "tsne", "--model", model, "--target-policy", target,
                             "--episodes", "1", "--marks", "2",
                             "--out", tmp_path / "tsne")  # fmt: skip
    assert code == 0, err
    numbers = json.loads((tmp_path / "tsne/numbers.json").read_text())
    assert 0.0 <= numbers["shared"]["agent_probe_accuracy"] <= 1.0
    for name in ("tsne_shared.png", "tsne_individual.png", "mark_1.png", "mark_2.png"):
        assert (tmp_path / "tsne" / name).stat().st_size > 0
    code, out, err = run_cli(capsys, "bound", "--model", model, "--target-policy", target,
                             "--episodes", "1")  # fmt: skip
    assert code == 0, err
    assert out.startswith("Theorem 1:") and ("(held)" in out or "(VIOLATED)" in out)
    code, out, err = run_cli(capsys, "video", "--policy", target, "--env", "pved/Reacher4Push-v0",
                             "--max-steps", "5", "--out", tmp_path / "v.gif")  # fmt: skip
    assert code == 0, err
    assert (tmp_path / "v.gif").stat().st_size > 0
    code, _, err = run_cli(capsys, "video", "--policy", target, "--env", "pved/Reacher4Push-v0",
                           "--with-policy", target, "--out", tmp_path / "w.gif")  # fmt: skip
    assert code == 2 and "--with-policy needs --with-env" in err
