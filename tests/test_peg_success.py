"""`pved analyze peg-success`: where on the table a Peg policy succeeds."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pved.diagnostics import peg_success

ROOT = Path(__file__).resolve().parents[1]
PVED = [sys.executable, "-m", "pved", "analyze", "peg-success"]
JACO_PEG = ROOT / "src" / "pved" / "pretrained" / "jaco_peg_seed0.pt"


@pytest.fixture(scope="module")
def stages(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A runs root with a tiny jaco-fetch PVED model (runs/jaco-fetch/model/pved/seed0) and
    a source bank (runs/jaco-fetch/bank/Jaco-Peg/seed0), made by the CLI from the shipped
    policies."""
    from pved.cli import main

    runs = tmp_path_factory.mktemp("stages") / "runs"
    for argv in (
        ["collect-pairs", "--episodes", "4"],
        ["train-model", "--epochs", "1"],
        ["build-bank", "--episodes", "4"],
    ):
        assert main([argv[0], "--runs", str(runs), "--pair", "jaco-fetch", *argv[1:]]) == 0
    assert (runs / "jaco-fetch/model/pved/seed0/model.pt").is_file()
    assert (runs / "jaco-fetch/bank/Jaco-Peg/seed0/bank.npz").is_file()
    return runs


def test_the_source_policy_follows_every_hole_of_the_grid(tmp_path: Path) -> None:
    # the shipped Jaco policy solves Peg everywhere: its tip must end on each grid hole's
    # axis, which it can only do if every copy was given its own hole
    out = tmp_path / "map.json"
    done = subprocess.run(
        [*PVED, str(JACO_PEG), "--agent", "jaco", "--grid", "3",
         "--copies", "2", "--json", str(out)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    result = json.loads(out.read_text())
    assert result["success_rate"] == 1.0
    assert result["success_by_hole"] == [[1.0] * 3] * 3
    assert result["follow_slope_x"] == pytest.approx(1.0, abs=0.05)
    assert result["follow_slope_y"] == pytest.approx(1.0, abs=0.05)
    assert result["tip_to_hole_axis_m_median"] < 0.005
    assert result["hole_x"] == pytest.approx([0.5, 0.55, 0.6])
    assert "success rate 1.000" in done.stdout


def test_a_policy_for_another_agent_is_a_one_line_error(tmp_path: Path) -> None:
    done = subprocess.run(
        [*PVED, str(JACO_PEG), "--agent", "fetch4", "--json",
         str(tmp_path / "map.json")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.startswith("pved: error:")
    assert done.stderr.count("\n") == 1 and "takes 30 observations" in done.stderr
    assert not (tmp_path / "map.json").exists()
    with pytest.raises(Exception, match="unknown agent 'ant'"):
        peg_success.success_map(JACO_PEG, "ant", 3, 1, 0)


def test_a_protocol_is_mapped_by_method_from_its_evaluation_runs(
    tmp_path: Path, stages: Path
) -> None:
    # a Fetch4 policy of the right size (the shipped Reach one: Peg's observation has as
    # many entries), an evaluation run of PVED, a tuning run that is not one, and a PPO
    # evaluation run restored without its policy
    protocol = tmp_path / "jaco-fetch-paper"
    transfer = protocol / "runs" / "jaco-fetch" / "transfer"
    record = {"pairs": ["jaco-fetch"], "budget": {"evaluation_seeds": [20000, 40000]}}
    (protocol).mkdir()
    (protocol / "protocol.json").write_text(json.dumps(record))
    fetch_policy = (ROOT / "src" / "pved" / "pretrained" / "fetch4_reach_seed0.pt").read_bytes()
    for name, has_policy in (
        ("pved-beta0.001-init0-src0/seed20000", True),
        ("pved-beta0.001-init0-src0/seed2000", True),
        ("ppo/seed40000", False),
        ("ppo/seed20000", True),  # unfinished: no result.json
    ):
        run = transfer / name
        run.mkdir(parents=True)
        if has_policy:
            (run / "policy.pt").write_bytes(fetch_policy)
        if name != "ppo/seed20000":
            (run / "result.json").write_text("{}")
    done = subprocess.run(
        [*PVED, str(protocol), "--grid", "2", "--copies", "1"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads((protocol / "subspaces" / "peg_success.json").read_text())
    assert summary["methods"]["ppo"] == {"runs": 0, "runs_without_policy": 1}
    pved = summary["methods"]["pved"]
    assert pved["runs"] == 1 and pved["runs_without_policy"] == 0
    assert [r["run"] for r in summary["runs"]["pved"]] == ["pved-beta0.001-init0-src0/seed20000"]
    assert "| ppo | 0 (1) |" in done.stdout and "| pved | 1 (0) |" in done.stdout
    assert summary["shaping_measured_under"] is None and pved["shaping_D_mean_median"] is None
    # once the selection has chosen PVED's model, D is measured under it and the
    # source-0 bank, for every method's runs alike
    for stage in ("model/pved/seed0", "bank/Jaco-Peg/seed0"):
        shutil.copytree(stages / "jaco-fetch" / stage, protocol / "runs" / "jaco-fetch" / stage)
    (protocol / "selection.json").write_text(json.dumps({"jaco-fetch": {"pved": {"init": 0}}}))
    peg_success.peg_success(protocol, grid=2, copies=1)
    summary = json.loads((protocol / "subspaces" / "peg_success.json").read_text())
    assert summary["shaping_measured_under"] == "pved init 0, source-0 bank"
    shaping = peg_success.load_shaping(stages / "jaco-fetch/model/pved/seed0",
                                  stages / "jaco-fetch/bank/Jaco-Peg/seed0")  # fmt: skip
    alone = peg_success.success_map(
        transfer / "pved-beta0.001-init0-src0/seed20000/policy.pt", "fetch4", 2, 1, 0, shaping
    )
    assert summary["methods"]["pved"]["shaping_D_mean_median"] == pytest.approx(
        alone["shaping_D_mean"]
    )
    # a directory of another pair is refused in one line
    record["pairs"] = ["walker-hopper"]
    (protocol / "protocol.json").write_text(json.dumps(record))
    refused = subprocess.run([*PVED, str(protocol)], capture_output=True, text=True)
    assert refused.returncode == 2 and "has no jaco-fetch runs" in refused.stderr


def test_eq10_distance_along_the_trajectories_is_the_transfer_runs_term(stages: Path) -> None:
    # D measured by the script must be what a transfer run's shaped env pays the same
    # policy at the same holes and starts: same bank episodes, same steps, beta = 1
    import numpy as np

    from pved.envs.arms import HOLE_CENTER_XY, TABLE_TOP_Z
    from pved.envs.registry import make_batched
    from pved.models.registry import load_model
    from pved.rl.policy import load_policy
    from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
    from pved.transfer.source_bank import load_bank

    model_dir = stages / "jaco-fetch/model/pved/seed0"
    bank_dir = stages / "jaco-fetch/bank/Jaco-Peg/seed0"
    policy_path = ROOT / "src" / "pved" / "pretrained" / "fetch4_reach_seed0.pt"

    shaping = peg_success.load_shaping(model_dir, bank_dir)
    result = peg_success.success_map(policy_path, "fetch4", 2, 1, 7, shaping)

    holes = np.array([(x, y) for y in result["hole_y"] for x in result["hole_x"]])
    model, bank = load_model(model_dir / "model.pt"), load_bank(bank_dir / "bank.npz")
    inner = make_batched("pved/Fetch4Peg-v0", len(holes))
    # the policy acts deterministically, so the action taken is its mean action
    env = ShapedBatchedEnv(
        inner,
        LatentShaping(model, bank, 1.0, inner.robot_state_indices, action="taken"),
        ("hole",),
    )
    policy = load_policy(policy_path)
    obs, info = env.reset(seed=7, options={"hole": holes})
    paid = np.zeros(len(holes))
    d_by_band: dict[str, list[float]] = {"in_hole": [], "at_table_top": [], "above_table_top": []}
    for _ in range(inner.max_episode_steps):
        z = np.asarray(info["peg_tip"])[:, 2]  # where the tip is as the action is taken
        obs, _, _, _, info = env.step(policy.act(obs, deterministic=True))
        paid += info["reward_shaping"]
        for zi, d in zip(z, -info["reward_shaping"], strict=True):
            below, above = zi < TABLE_TOP_Z - 0.005, zi >= TABLE_TOP_Z + 0.005
            band = "in_hole" if below else "above_table_top" if above else "at_table_top"
            d_by_band[band].append(d)
    assert result["shaping_D_mean"] == pytest.approx(-paid.mean() / inner.max_episode_steps)
    assert result["shaping_D_mean"] > 0
    # D by the tip's height, band by band, as the script groups it
    # against the source at the reflected hole: every hole of a 2 x 2 grid is a corner,
    # far enough from the centre; the same policy steps, the other hole's bank episode
    shaping_per_step = LatentShaping(model, bank, 1.0, inner.robot_state_indices)
    own_ep = bank.match(holes, None)
    reflected_ep = bank.match(2 * np.asarray(HOLE_CENTER_XY) - holes, None)
    assert not np.array_equal(own_ep, reflected_ep)
    plain = make_batched("pved/Fetch4Peg-v0", len(holes))
    obs, _ = plain.reset(seed=7, options={"hole": holes})
    d_own, d_reflected = np.zeros(len(holes)), np.zeros(len(holes))
    for t in range(plain.max_episode_steps):
        action = policy.act(obs, deterministic=True)
        at = np.full(len(holes), t)
        d_own -= shaping_per_step.reward(obs, action, own_ep, at)
        d_reflected -= shaping_per_step.reward(obs, action, reflected_ep, at)
        obs, *_ = plain.step(action)
    own = result["shaping_D_own_vs_reflected_hole"]
    assert own["episodes"] == len(holes)
    assert own["own_D_median"] == pytest.approx(np.median(d_own) / plain.max_episode_steps)
    assert own["reflected_D_median"] == pytest.approx(
        np.median(d_reflected) / plain.max_episode_steps
    )
    assert own["own_lower_share"] == pytest.approx(np.mean(d_own < d_reflected))
    assert own["own_D_median"] != pytest.approx(own["reflected_D_median"])
    steps = sum(len(v) for v in d_by_band.values())
    by_height = result["shaping_D_by_tip_height"]
    for band, ds in d_by_band.items():
        assert by_height[band]["share_of_steps"] == pytest.approx(len(ds) / steps)
        if ds:
            assert by_height[band]["D_median"] == pytest.approx(float(np.median(ds)))
        else:
            assert by_height[band]["D_median"] is None
    # the two inputs go together
    done = subprocess.run(
        [*PVED, str(policy_path), "--shaping-model", str(model_dir)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 2 and "--shaping-model and --bank go together" in done.stderr
