"""Pair spec files (issue 52): the four built-in pairs are specs that say exactly what
their presets said; ``pved pair show`` / ``pved pair check`` round-trip them; a spec's
mistakes are one line each; files made under another spec are refused."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import run_cli
from pved.config import PRETRAINED
from pved.envs.gym_adapter import GymnasiumBatch
from pved.envs.registry import env_id
from pved.errors import PvedError
from pved.experiments import stages
from pved.runs import Run, config_hash
from pved.spec import PRESETS, builtin_names, dump_pair, get_preset, load_pair, read_spec

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "pairs"
# every field of the four presets as config.py built them before specs existed (reprs)
FROZEN = json.loads((Path(__file__).parent / "frozen_presets.json").read_text())
PAIRS = ("reacher", "jaco-fetch", "walker-hopper", "humanoid-ant")


def refused(capsys: pytest.CaptureFixture[str], *argv: object, match: str) -> None:
    """``pved ARGV`` exits with 2 and one ``pved: error:`` line holding ``match``."""
    code, _, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("pved: error:"), err
    assert match in lines[0], lines[0]


def shown(capsys: pytest.CaptureFixture[str], pair: str, path: Path) -> Path:
    code, out, err = run_cli(capsys, "pair", "show", pair)
    assert code == 0, err
    path.write_text(out)
    return path


# -- the built-in pairs ----------------------------------------------------------------
def test_the_builtin_pairs_are_the_four_shipped_specs() -> None:
    assert builtin_names() == sorted(PAIRS) == sorted(PRESETS)


@pytest.mark.parametrize("pair", PAIRS)
def test_a_builtin_spec_says_what_its_preset_said(pair: str) -> None:
    preset = get_preset(pair)
    for name, frozen in FROZEN[pair].items():
        assert repr(getattr(preset, name)) == frozen, name
    for agent in (preset.source_agent, preset.target_agent):
        assert preset.robot_state_of(agent) is None  # the pved envs report their own
        for task in (preset.training_task, preset.target_task):
            entry = preset.agent_env(agent, task)
            assert (entry.env_id, entry.kwargs, entry.policy) == (
                env_id(agent, task),
                (),
                PRETRAINED,
            )


@pytest.mark.parametrize("pair", PAIRS)
def test_a_shown_spec_runs_every_stage_as_the_name_does(
    pair: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    spec = shown(capsys, pair, tmp_path / f"{pair}.toml")
    assert read_spec(spec) == get_preset(pair)
    assert load_pair(spec) is not None and get_preset(pair) == read_spec(spec)
    # the same runs: every stage resolves to the same directory and config hash
    hashes: dict[str, list[tuple[Path, str]]] = {}

    def record(run: Run) -> None:
        hashes.setdefault(key, []).append((run.path, run.hash))
        raise RuntimeError("started")

    monkeypatch.setattr(Run, "start", record)
    runs = tmp_path / "runs"
    for key in (pair, str(spec)):
        for stage in ("collect_pairs", "build_bank"):
            with pytest.raises(RuntimeError, match="started"):
                getattr(stages, stage)(key, episodes=2, runs_root=runs)
        model, bank = tmp_path / "model.pt", tmp_path / "bank.npz"
        model.write_bytes(b"model")
        bank.write_bytes(b"bank")
        for method in ("ppo", "pved"):
            t = stages.transfer_spec(key, method, runs_root=runs, model_path=model, bank_path=bank)
            hashes.setdefault(key, []).append((t.run_dir, config_hash(t.config)))
    assert hashes[pair] == hashes[str(spec)]
    # and `pair check` passes on the printed file
    code, out, err = run_cli(capsys, "pair", "check", spec)
    assert code == 0 and out.strip().endswith("ok"), err


def test_dump_reads_back_for_every_field(tmp_path: Path) -> None:
    preset = dataclasses.replace(
        get_preset("walker-hopper"), metric_resolution=None, beta_grid=(1.0, 0.5)
    )
    path = tmp_path / "x.toml"
    path.write_text(dump_pair(preset))
    assert read_spec(path) == preset


# -- mistakes: one line naming the field -------------------------------------------------
def _edited(tmp_path: Path, old: str, new: str, example: str = "pendulums") -> Path:
    text = (EXAMPLES / f"{example}.toml").read_text()
    assert old in text
    path = tmp_path / "spec.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ('env = "InvertedPendulum-v5"', 'env = "InvertedPendulim-v5"', "unknown env id"),
        ('env = "InvertedPendulum-v5"', 'env = "pved/Nope-v0"', "unknown env id"),
        ("# robot_state: omitted", "robot_state = [0, 1, 9]\n#", "robot state index 9"),
        ('name = "pendulums"', "", "name is missing"),
        ('[target]\nagent = "Pendulum2"', "[target]", "target.agent is missing"),
        ("shared = []", 'shared = ["target"]', "tasks.shared: 'target' is not in"),
        ("[model]", "[model]\nalpha4 = 1.0", "model.alpha4 is not a field of PVEDConfig"),
        ("alpha1 = 1.0", "alpha1 = -1.0", "alpha1"),
        ('name = "return_mean"', 'name = "distance"', "metric.name"),
        ('name = "pendulums"', 'name = "reacher"', "is a built-in pair's"),
        ("kwargs = { reset_noise_scale = 0.1 }", "kwargs = { noise = 0.1 }", "noise"),
    ],
)
def test_a_spec_mistake_is_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str, match: str
) -> None:
    refused(capsys, "pair", "check", _edited(tmp_path, old, new), "--runs", tmp_path, match=match)


def test_a_policy_of_the_wrong_dims_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pved.pretrained import pretrained_policy_path

    reacher = pretrained_policy_path("Reacher3", "Reach")
    spec = _edited(
        tmp_path,
        '[source.target]\nenv = "InvertedPendulum-v5"',
        f'[source.target]\nenv = "InvertedPendulum-v5"\npolicy = "{reacher}"',
    )
    refused(capsys, "pair", "check", spec, match="source.target.policy")
    refused(capsys, "build-bank", "--pair", spec, "--runs", tmp_path,
            match="the policy observes 15 dims, the env 4")  # fmt: skip
    refused(capsys, "pair", "check", "no-such.toml", match="spec not found")
    refused(capsys, "transfer", "--pair", spec, "--model", "oracle", "--runs", tmp_path,
            match="no such variant")  # fmt: skip
    refused(capsys, "collect-pairs", "--pair", "nope", match="unknown pair 'nope'")


def test_gymnasium_batch_gives_each_copy_its_row_of_the_options() -> None:
    env = GymnasiumBatch(env_id="InvertedPendulum-v5", num_envs=2)
    seen: list[Any] = []
    for copy in env.envs:
        reset = copy.reset

        def record(*args: Any, _reset: Any = reset, **kwargs: Any) -> Any:
            seen.append(kwargs.get("options"))
            return _reset(seed=kwargs.get("seed"))

        copy.reset = record  # type: ignore[method-assign]
    env.reset(seed=0, options={"goal": np.array([[1.0, 2.0], [3.0, 4.0]])})
    assert [list(o["goal"]) for o in seen] == [[1.0, 2.0], [3.0, 4.0]]
    assert env.dt == pytest.approx(0.04)


def test_any_gymnasium_id_is_batched_module_form_included() -> None:
    from pved.envs import make_batched

    env = make_batched("gymnasium.envs.mujoco.reacher_v5:Reacher-v5", 3, robot_state=[0, 1, 6])
    obs, _ = env.reset(seed=0)
    assert obs.shape == (3, 10) and list(env.robot_state_indices) == [0, 1, 6]
    with pytest.raises(PvedError, match="reports its robot state"):
        make_batched("pved/Reacher3Reach-v0", 1, robot_state=[0])


# -- two pairs of stock Gymnasium envs, from a spec file and the CLI alone -----------------
SMOKE = {
    "train-policy": ["--steps", "2048", "--eval-episodes", "2"],
    "collect-pairs": ["--episodes", "16"],
    "train-model": ["--epochs", "2"],
    "build-bank": ["--episodes", "8"],
    "transfer": "--steps 2048 --eval-every 0 --eval-episodes 4 --final-eval-episodes 8".split(),
}


def _pipeline(capsys: pytest.CaptureFixture[str], spec: Path, runs: Path) -> dict[str, Any]:
    preset = read_spec(spec)
    src, tgt = preset.source_agent, preset.target_agent
    for agent, task in ((src, preset.training_task), (tgt, preset.training_task),
                        (src, preset.target_task)):  # fmt: skip
        code, _, err = run_cli(
            capsys, "train-policy", "--pair", spec, "--agent", agent, "--task", task,
            "--runs", runs, *SMOKE["train-policy"],
        )  # fmt: skip
        assert code == 0, err
    code, out, err = run_cli(capsys, "pair", "check", spec, "--runs", runs)
    assert code == 0 and "not trained" not in out, err
    for verb in ("collect-pairs", "train-model", "build-bank", "transfer"):
        code, out, err = run_cli(capsys, verb, "--pair", spec, "--runs", runs, *SMOKE[verb])
        assert code == 0, err
    result = json.loads(out)
    code, out, err = run_cli(
        capsys, "evaluate", "--pair", spec, "--policy", result["policy"], "--episodes", "4"
    )
    assert code == 0, err
    return {"transfer": result, "evaluate": json.loads(out)}


@pytest.fixture(scope="module")
def pendulums(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("pendulums") / "runs"


@pytest.mark.slow
def test_stock_pendulums_run_every_stage_from_the_spec(
    pendulums: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _pipeline(capsys, EXAMPLES / "pendulums.toml", pendulums)
    assert out["transfer"]["final/episodes"] == 8 and out["evaluate"]["episodes"] == 4
    assert (pendulums / "pendulums" / "bank" / "Pendulum1-Recover" / "seed0" / "bank.npz").exists()


@pytest.mark.slow
def test_stock_hopper_walker_runs_every_stage_from_the_spec(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _pipeline(capsys, EXAMPLES / "hopper-walker.toml", tmp_path / "runs")
    assert np.isfinite(out["evaluate"]["x_position_mean"])


@pytest.mark.slow
def test_files_made_under_another_spec_or_pair_are_refused(
    pendulums: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = pendulums / "pendulums"
    if not (runs / "model" / "pved" / "seed0" / "model.pt").exists():
        pytest.skip("needs the pendulums pipeline's files")
    # the same name, another target task: the dataset, model and bank are another spec's
    spec = _edited(tmp_path, "reset_noise_scale = 0.3", "reset_noise_scale = 0.4")
    dataset = runs / "pairs" / "subsample" / "seed0"
    model, bank = runs / "model" / "pved" / "seed0", runs / "bank" / "Pendulum1-Recover" / "seed0"
    refused(capsys, "train-model", "--pair", spec, "--dataset", dataset, "--runs", tmp_path,
            match="another spec of pendulums")  # fmt: skip
    refused(capsys, "transfer", "--pair", spec, "--model-path", model, "--bank", bank,
            "--runs", tmp_path, match="another spec of pendulums")  # fmt: skip
    # this pair's files for a built-in pair
    refused(capsys, "transfer", "--pair", "reacher", "--model-path", model, "--bank", bank,
            "--runs", tmp_path, match="another pair")  # fmt: skip


def _pair_name_in_a_fresh_process(name: str) -> str:
    from pved.spec import load_pair

    return load_pair(name).name


def test_a_spec_loaded_here_is_found_by_name_in_spawned_workers() -> None:
    # a protocol's workers are fresh interpreters (spawned, or Ray's): they look the pair
    # up by name, and find the spec file this process read through the environment
    import concurrent.futures
    import multiprocessing

    from pved.spec import load_pair

    spec = Path(__file__).resolve().parents[1] / "examples/pairs/pendulums.toml"
    name = load_pair(spec).name
    with concurrent.futures.ProcessPoolExecutor(
        1, mp_context=multiprocessing.get_context("spawn")
    ) as pool:
        assert pool.submit(_pair_name_in_a_fresh_process, name).result() == name
        with pytest.raises(PvedError, match="unknown pair 'no-such-pair'"):
            pool.submit(_pair_name_in_a_fresh_process, "no-such-pair").result()
