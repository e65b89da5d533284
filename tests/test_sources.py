"""Sources from where users have them (issue 52): an SB3 ``.zip`` policy and a Minari
dataset of recorded episodes each serve as the source of build-bank and collect-pairs on
the reacher pair, and a source made for another agent is refused in one line before any
work."""

from __future__ import annotations

import json
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from helpers import run_cli, stock_reacher_spec
from pved.envs import make_batched
from pved.envs.registry import make
from pved.errors import PvedError
from pved.experiments.sources import export_source_dataset
from pved.experiments.stages import build_bank, collect_pairs, evaluate
from pved.pairing.dataset import load_dataset
from pved.pairing.minari_io import open_recorded, read_recorded_episodes
from pved.rl.external import SB3Policy, load_policy_file
from pved.transfer.source_bank import load_bank

sb3 = pytest.importorskip("stable_baselines3")
minari = pytest.importorskip("minari")

REACH, PUSH = "pved/Reacher3Reach-v0", "pved/Reacher3Push-v0"


def _train_ppo(env: gym.Env, path: Path, steps: int = 1024) -> Path:
    """A small SB3 PPO trained for a few seconds (what it learns does not matter here:
    that pved rolls out exactly what SB3 would)."""
    torch.set_num_threads(1)
    model = sb3.PPO(
        "MlpPolicy",
        env,
        n_steps=256,
        batch_size=64,
        n_epochs=1,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        device="cpu",
    )
    if steps:
        model.learn(steps)
    model.save(path)
    return path


@pytest.fixture(scope="module")
def sb3_zips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("sb3")
    return {
        "reach": _train_ppo(make(REACH), out / "ppo_reach.zip"),
        "push": _train_ppo(make(PUSH), out / "ppo_push.zip"),
    }


@pytest.fixture
def datasets_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Minari's datasets folder, inside the test's own directory."""
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    yield root


def one_line_error(capsys: pytest.CaptureFixture[str], *argv: object, match: str) -> None:
    code, _, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("pved: error:"), err
    assert match in lines[0], lines[0]


# ------------------------------------------------------------------------------- SB3
def test_sb3_policy_acts_as_sb3_predicts(sb3_zips: dict[str, Path]) -> None:
    policy = load_policy_file(sb3_zips["reach"])
    assert isinstance(policy, SB3Policy) and (policy.obs_dim, policy.act_dim) == (15, 3)
    obs, _ = make_batched(REACH, 5).reset(seed=1)
    want, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(policy.act(obs, deterministic=True), want)
    # sampled actions: the policy's own Gaussian around that mean, repeatable from the rng
    a = policy.act(obs, rng=np.random.default_rng(3))
    b = policy.act(obs, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, want) and np.all(np.abs(a) <= 1.0)


@pytest.mark.parametrize("algorithm", ["A2C", "SAC", "TD3", "DDPG"])
def test_other_sb3_algorithms_load_as_their_own(algorithm: str, tmp_path: Path) -> None:
    torch.set_num_threads(1)
    kwargs = {"policy_kwargs": {"net_arch": [8]}, "seed": 0, "device": "cpu"}
    if algorithm != "A2C":
        kwargs["buffer_size"] = 100
    getattr(sb3, algorithm)("MlpPolicy", make(PUSH), **kwargs).save(tmp_path / "m.zip")
    policy = load_policy_file(tmp_path / "m.zip", env=make_batched(PUSH, 3), env_name=PUSH)
    assert isinstance(policy, SB3Policy)
    assert policy.metadata["algorithm"] == {"A2C": "PPO", "DDPG": "TD3"}.get(algorithm, algorithm)
    obs, _ = make_batched(PUSH, 3).reset(seed=2)
    want, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(policy.act(obs, deterministic=True), want)
    sampled = policy.act(obs, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(sampled, policy.act(obs, rng=np.random.default_rng(0)))
    assert sampled.shape == (3, 3) and np.all(np.abs(sampled) <= 1.0)


def test_sb3_policy_is_the_source_of_build_bank_and_collect_pairs(
    sb3_zips: dict[str, Path], tmp_path: Path
) -> None:
    runs = tmp_path / "runs"
    bank = load_bank(
        build_bank("reacher", source_policy=sb3_zips["push"], episodes=4, runs_root=runs)
    )
    assert bank.header["source_policy"] == str(sb3_zips["push"]) and bank.x.shape[0] == 4
    # the bank's first actions are SB3's own deterministic predictions at the resets
    obs, _ = make_batched(PUSH, 4).reset(seed=0)
    model = sb3.PPO.load(sb3_zips["push"], device="cpu")
    state_dim = len(bank.header["robot_state_indices"])
    want, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(bank.x[:, 0, state_dim:], want, rtol=0, atol=1e-7)

    pairs = load_dataset(
        collect_pairs(
            "reacher", source_policy=sb3_zips["reach"], episodes=4, runs_root=runs, progress=False
        )
    )
    assert pairs.header["source_policy"] == str(sb3_zips["reach"])
    # and evaluated as any policy is
    assert evaluate(sb3_zips["push"], PUSH, episodes=2)["episodes"] == 2
    first = pairs.t_source == 0
    obs, _ = make_batched(REACH, 16).reset(seed=0)
    want, _ = sb3.PPO.load(sb3_zips["reach"], device="cpu").predict(obs[:4], deterministic=True)
    np.testing.assert_allclose(pairs.act_source[first], want, rtol=0, atol=1e-7)


def test_sb3_policy_for_another_agent_is_refused_before_any_work(
    sb3_zips: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    # the Reach policy observes 15 dims, the bank's env (Reacher3 on Push) 18
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-policy", sb3_zips["reach"],
                   match=f"policy {sb3_zips['reach']} and {PUSH} do not match: the policy "
                   "observes 15 dims, the env 18")  # fmt: skip
    # as the target's policy (Reacher4 observes 18)
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--target-policy",
                   sb3_zips["reach"], match="observes 15 dims, the env 18")  # fmt: skip
    # the right dims, but trained on other action bounds
    two = np.full(3, 2.0, dtype=np.float32)
    wide = _train_ppo(gym.wrappers.RescaleAction(make(PUSH), -two, two), tmp_path / "w.zip", 0)
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-policy", wide,
                   match=f"acts within [-2, 2], {PUSH}'s actions within [-1, 1]")  # fmt: skip
    assert not list(runs.rglob("result.json")) and not list(runs.rglob("bank.npz"))


def test_sb3_file_problems_are_one_line(
    sb3_zips: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    other = tmp_path / "recurrent.zip"
    with zipfile.ZipFile(other, "w") as archive:
        archive.writestr("data", json.dumps({"policy_class": {"__module__": "sb3_contrib.x"}}))
        archive.writestr("policy.pth", b"")
    with pytest.raises(PvedError, match=r"is a sb3_contrib\.x policy; pved reads PPO"):
        load_policy_file(other)
    with pytest.raises(PvedError, match="policy not found"):
        load_policy_file(tmp_path / "none.zip")
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # SB3 not installed
    with pytest.raises(PvedError, match=r"pip install pved\[sb3\]"):
        load_policy_file(sb3_zips["reach"])


# ---------------------------------------------------------------------------- Minari
def test_minari_dataset_is_the_source_of_build_bank_as_the_rollouts_are(
    datasets_root: Path, tmp_path: Path
) -> None:
    folder = export_source_dataset("reacher", "reacher3-push-v0", episodes=5, seed=3)
    assert folder == datasets_root / "reacher3-push-v0"
    direct = load_bank(build_bank("reacher", episodes=5, seed=3, runs_root=tmp_path / "a"))
    recorded = load_bank(
        build_bank("reacher", source_dataset="reacher3-push-v0", runs_root=tmp_path / "b")
    )
    # the same episodes (same seeds, same batch): equal bit for bit
    np.testing.assert_array_equal(recorded.x, direct.x)
    np.testing.assert_array_equal(recorded.lengths, direct.lengths)
    np.testing.assert_array_equal(recorded.keys, direct.keys)
    for key in ("env_id", "match_keys", "success_rate", "robot_state_indices", "dt"):
        assert recorded.header[key] == direct.header[key], key
    source = recorded.header["source_dataset"]
    assert source["dataset_id"] == "reacher3-push-v0" and source["env_id"] == PUSH
    assert source["pved"]["seed"] == 3 and len(source["digest"]) == 16
    # by folder too, and only the first episodes when asked
    part = load_bank(
        build_bank("reacher", source_dataset=str(folder), episodes=2, runs_root=tmp_path / "c")
    )
    np.testing.assert_array_equal(part.x, direct.x[:2, : part.x.shape[1]])


def test_minari_dataset_is_the_source_of_pairing_as_the_rollouts_are(
    datasets_root: Path, tmp_path: Path
) -> None:
    export_source_dataset("reacher", "pved/reacher3-reach-v0", task="Reach", episodes=5)
    direct = load_dataset(
        collect_pairs("reacher", episodes=5, runs_root=tmp_path / "a", progress=False)
    )
    recorded = load_dataset(
        collect_pairs(
            "reacher",
            source_dataset="pved/reacher3-reach-v0",
            runs_root=tmp_path / "b",
            progress=False,
        )
    )
    for name in ("obs_source", "act_source", "obs_target", "act_target", "t_source", "t_target"):
        np.testing.assert_array_equal(getattr(recorded, name), getattr(direct, name), name)
    np.testing.assert_array_equal(recorded.task["target"], direct.task["target"])
    assert recorded.header["source_dataset"]["dataset_id"] == "pved/reacher3-reach-v0"
    assert "source_policy" not in recorded.header


def test_recorded_episodes_keep_what_minari_holds(datasets_root: Path) -> None:
    export_source_dataset("reacher", "push-v1", episodes=3, seed=7)
    data = open_recorded("push-v1")
    assert (data.env_id, data.obs_dim, data.act_dim, data.episodes) == (PUSH, 18, 3, 3)
    episodes = read_recorded_episodes(data, ("button_start",))
    raw = minari.load_dataset("push-v1")
    for ep, mine in zip(raw.iterate_episodes(), episodes, strict=True):
        np.testing.assert_array_equal(ep.observations[:-1], mine.obs)
        np.testing.assert_array_equal(ep.observations[-1], mine.final_obs)
        np.testing.assert_array_equal(ep.actions, mine.act)
        assert mine.reward is not None
        np.testing.assert_array_equal(ep.rewards, mine.reward)
    assert [m["seed"] for m in raw.storage.get_episode_metadata(range(3))] == [7, 8, 9]


def _foreign_dataset(dataset_id: str, obs_dim: int, infos: dict | None = None) -> None:
    """A Minari dataset made outside pved: no env spec, only spaces."""
    from minari.data_collector import EpisodeBuffer

    steps = 4
    buffer = EpisodeBuffer(
        observations=np.zeros((steps + 1, obs_dim)),
        actions=np.zeros((steps, 3), dtype=np.float32),
        rewards=np.zeros(steps),
        terminations=np.zeros(steps, dtype=bool),
        truncations=np.eye(1, steps, steps - 1, dtype=bool)[0],
        infos=infos,
    )
    with pytest.warns(UserWarning):  # Minari asks for an author, a permalink, ...
        minari.create_dataset_from_buffers(
            dataset_id,
            [buffer],
            observation_space=gym.spaces.Box(-np.inf, np.inf, (obs_dim,)),
            action_space=gym.spaces.Box(-1, 1, (3,)),
        )


def test_datasets_for_another_agent_are_refused_before_any_work(
    datasets_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    export_source_dataset("reacher", "reach-v0", task="Reach", episodes=2)
    # recorded on the training task's env, given as the bank's (target task) source
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-dataset", "reach-v0",
                   match=f"Minari dataset reach-v0 was recorded on {REACH}, the source's env "
                   f"is {PUSH}")  # fmt: skip
    # no env spec: its sizes decide
    _foreign_dataset("small-v0", 7)
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-dataset", "small-v0",
                   match="Minari dataset small-v0 has observations of 7 dims, "
                   "pved/Reacher3Push-v0 of 18")  # fmt: skip
    # the right sizes but no task parameters to match or reset the target with
    _foreign_dataset("taskless-v0", 18)
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-dataset", "taskless-v0",
                   match="episode 0: no task parameter 'button_start'")  # fmt: skip
    one_line_error(capsys, "build-bank", "--runs", runs, "--source-dataset", "nothing-v0",
                   match="Minari dataset 'nothing-v0' not found")  # fmt: skip
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--source-dataset", "reach-v0",
                   "--episodes", "3", match="holds 2 episodes, 3 were asked for")  # fmt: skip
    one_line_error(capsys, "collect-pairs", "--runs", runs, "--source-dataset", "reach-v0",
                   "--source-policy", tmp_path, match="--source-dataset must be given without "
                   "--source-policy")  # fmt: skip
    one_line_error(capsys, "export-minari", "reach-v0", "--task", "Reach",
                   match="Minari dataset reach-v0 already exists")  # fmt: skip
    one_line_error(capsys, "export-minari", "new-v0", "--episodes", "0",
                   match="--episodes must be an integer >= 1")  # fmt: skip
    one_line_error(capsys, "export-minari", "new id", match="Malformed dataset ID")  # fmt: skip
    assert sorted(p.name for p in datasets_root.iterdir()) == [
        "reach-v0",
        "small-v0",
        "taskless-v0",
    ]
    assert not list(runs.rglob("result.json")) and not list(runs.rglob("*.npz"))


def test_a_task_parameter_in_the_first_info_is_read(datasets_root: Path) -> None:
    # a Gymnasium env reports its task in the reset info: Minari keeps it as infos' row 0
    start = np.tile([[0.1, -0.1]], (5, 1))
    _foreign_dataset("infos-v0", 18, infos={"button_start": start})
    (episode,) = read_recorded_episodes(open_recorded("infos-v0"), ("button_start",))
    np.testing.assert_array_equal(episode.reset_info["button_start"], [0.1, -0.1])


def test_without_minari_the_error_says_what_to_install(
    datasets_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    export_source_dataset("reacher", "push-v0", episodes=1)
    monkeypatch.setitem(sys.modules, "minari", None)
    with pytest.raises(PvedError, match=r"pip install pved\[minari\]"):
        open_recorded("push-v0")


# ------------------------------------------------------------- a pair pved has never seen
def test_a_spec_pairs_own_agents_go_through_export_minari_bank_and_pairs(
    datasets_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # stock Reacher-v5 (SB3 policies named by the spec) -> pved's Reacher3: export-minari
    # finds the source's env, arguments and policy in the spec as the other verbs do
    spec = stock_reacher_spec(tmp_path / "spec")
    runs = tmp_path / "runs"

    def cli(*argv: object) -> str:
        code, out, err = run_cli(capsys, *argv)
        assert code == 0, err
        return out.strip()

    cli("export-minari", "stock-push-v0", "--pair", spec, "--episodes", "3", "--seed", "4")
    cli("export-minari", "stock-reach-v0", "--pair", spec, "--task", "Reach", "--episodes", "3")
    data = open_recorded("stock-push-v0")
    assert (data.env_id, data.obs_dim, data.act_dim, data.episodes) == ("Reacher-v5", 10, 2, 3)
    assert data.provenance["pved"]["agent"] == "StockReacher2"
    assert data.provenance["pved"]["policy"] == str(spec.parent / "stock_push.zip")
    recorded = load_bank(Path(cli("build-bank", "--pair", spec, "--runs", runs / "a",
                                  "--source-dataset", "stock-push-v0")))  # fmt: skip
    direct = load_bank(Path(cli("build-bank", "--pair", spec, "--runs", runs / "b",
                                "--episodes", "3", "--seed", "4")))  # fmt: skip
    # the spec's target-task env arguments and robot state, bit for bit the direct rollouts
    # as far as the recorded episodes go: Reacher-v5's own 50 steps, where build-bank's own
    # rollouts run on to cover the target's 100-step episode (issue 64; the steps past a
    # recorded episode's end are compared with nothing, transfer.source_bank)
    short = recorded.x.shape[1]
    assert (short, direct.x.shape[1]) == (50, 100)
    np.testing.assert_array_equal(recorded.x, direct.x[:, :short])
    assert recorded.header["robot_state_indices"] == [0, 1, 2, 3, 6, 7]
    pairs = load_dataset(Path(cli("collect-pairs", "--pair", spec, "--runs", runs / "a",
                                  "--source-dataset", "stock-reach-v0")))  # fmt: skip
    assert pairs.header["source_dataset"]["env_id"] == "Reacher-v5"
    assert pairs.header["target_env_id"] == REACH and len(set(pairs.episode.tolist())) == 3
