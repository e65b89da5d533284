"""A pair resolved once, at the door: its spec, identity digest, envs and run layout.

``--pair NAME | SPEC.toml`` is turned into a :class:`Pair` by :func:`resolve_pair` where
a command (or a Python caller) starts, and that object is passed down: the stages, the
checks in :mod:`pved.run_layout` and the protocol read its fields and never look the
pair up by name again (docs/decisions/layout.md, "A pair is resolved at the door").

A resolved pair is a value (a frozen dataclass of frozen dataclasses), so it pickles
into a protocol's worker processes as it is: a spec read from a file needs no reading
there.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from pved.config import PairPreset
from pved.envs import make_batched
from pved.runs import run_path
from pved.spec import load_pair, spec_identity

#: Where the stages keep their run directories unless told otherwise (``--runs``).
DEFAULT_RUNS = Path("runs")


@dataclasses.dataclass(frozen=True)
class PairRuns:
    """Where one pair's stages write under one runs root:
    ``<root>/<pair>/<stage>/<name>/seed<k>`` (:func:`pved.runs.run_path`)."""

    root: Path
    pair: str

    def run(self, stage: str, name: str, seed: int) -> Path:
        """The run directory of ``stage``'s run ``name`` with ``seed``."""
        return run_path(self.root, self.pair, stage, name, seed)

    def dataset(self, align: str, seed: int = 0) -> Path:
        """The paired dataset ``collect_pairs`` writes for alignment ``align``."""
        return self.run("pairs", align, seed) / "pairs.npz"

    def model(self, model: str, seed: int = 0) -> Path:
        """The model ``train_model`` fits, ``model`` with ``seed``."""
        return self.run("model", model, seed) / "model.pt"

    def bank(self, agent: str, task: str, seed: int = 0) -> Path:
        """The source bank ``build_bank`` rolls out, ``agent`` on ``task``."""
        return self.run("bank", f"{agent}-{task}", seed) / "bank.npz"

    def policy(self, agent: str, task: str, seed: int = 0) -> Path:
        """The policy ``train_policy`` trains, ``agent`` on ``task``."""
        return self.run("policy", f"{agent}-{task}", seed) / "policy.pt"


@dataclasses.dataclass(frozen=True)
class Pair:
    """One agent pair, resolved: everything a stage needs to know about the pair.

    Attributes:
        preset: the pair's spec (:class:`~pved.config.PairPreset`).
        identity: the entry a run's config and a file's header carry for a pair that is
            not a built-in one (``{"spec": digest}``; empty for a built-in pair,
            :func:`pved.spec.spec_identity`).
        runs: where its stages' run directories lie (:class:`PairRuns`).
    """

    preset: PairPreset
    identity: dict[str, Any]
    runs: PairRuns
    # (agent, task) -> (obs dim, action dim), filled on first ask (it makes an env)
    _dims: dict[tuple[str, str], tuple[int, int]] = dataclasses.field(
        default_factory=dict, compare=False, repr=False
    )

    @property
    def name(self) -> str:
        """The name its run directories and files are kept under."""
        return self.preset.name

    def env(self, agent: str, task: str) -> tuple[str, dict[str, Any]]:
        """``agent``'s env on ``task``: its id, and the arguments
        :func:`~pved.envs.make_batched` takes for it (the spec's ``kwargs``, and its
        ``robot_state`` where the spec names one)."""
        entry = self.preset.agent_env(agent, task)
        kwargs: dict[str, Any] = dict(entry.kwargs)
        state = self.preset.robot_state_of(agent)
        if state is not None:
            kwargs["robot_state"] = state
        return entry.env_id, kwargs

    @property
    def target_env(self) -> tuple[str, dict[str, Any]]:
        """The env transfer trains and evaluates on: the target agent's on the target task."""
        return self.env(self.preset.target_agent, self.preset.target_task)

    @property
    def bank_env(self) -> tuple[str, dict[str, Any]]:
        """The env a source bank is rolled out on: the source agent's on the target task."""
        return self.env(self.preset.source_agent, self.preset.target_task)

    def dims(self, agent: str, task: str) -> tuple[int, int]:
        """``agent``'s observation and action dimensions on ``task`` (from its env)."""
        key = (agent, task)
        if key not in self._dims:
            name, kwargs = self.env(agent, task)
            env = make_batched(name, 1, **kwargs)
            try:
                obs = env.single_observation_space.shape
                act = env.single_action_space.shape
                assert obs is not None and act is not None
                self._dims[key] = (int(obs[0]), int(act[0]))
            finally:
                env.close()
        return self._dims[key]

    def at(self, runs_root: Path | str) -> Pair:
        """The same pair with its run directories under ``runs_root``."""
        return dataclasses.replace(self, runs=PairRuns(Path(runs_root), self.name))


def resolve_pair(pair: str | Path | PairPreset | Pair, runs_root: Path | str | None = None) -> Pair:
    """``pair`` resolved: a built-in name or a spec file (:func:`pved.spec.load_pair`;
    :class:`~pved.errors.PvedError` for an unknown one) or a spec already read, its run
    directories under ``runs_root`` (default :data:`DEFAULT_RUNS`). A :class:`Pair` is
    returned as it is, or moved to ``runs_root`` when one is given."""
    if isinstance(pair, Pair):
        return pair if runs_root is None else pair.at(runs_root)
    preset = pair if isinstance(pair, PairPreset) else load_pair(pair)
    root = DEFAULT_RUNS if runs_root is None else Path(runs_root)
    return Pair(preset, spec_identity(preset), PairRuns(root, preset.name))
