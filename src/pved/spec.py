"""Pair spec files: one agent pair's experiment as TOML data (docs/pairs.md).

A spec says everything a :class:`~pved.config.PairPreset` holds: both agents' envs on the
training and the target task, their robot-state indices and policies, the task
parameters that paired episodes share and those a bank is matched on, the alignment, the
metric, Table 1's alphas, beta and its grid, the PPO configs and budgets. The four
built-in pairs are specs shipped in ``pved/pairs/``; :func:`load_pair` reads a built-in
name or a file, :func:`dump_pair` writes the file back (``pved pair show``).

A spec loaded from a file is remembered under its name for the rest of the process, so
that every stage that looks a pair up by name (``get_preset``) finds it, and in the
environment variable ``PVED_SPEC_FILES``, so that the processes the process starts (a
protocol's workers, spawned or Ray's) find it too.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import tomllib
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

from pved.config import PRETRAINED, TRAINED, AgentEnv, PairingConfig, PairPreset, TransferConfig
from pved.errors import PvedError
from pved.models.pved import PVEDConfig
from pved.rl.ppo import PPOConfig

PAIRS_DIR = Path(__file__).resolve().parent / "pairs"
#: A TOML value that stands for Python's None (TOML has no null).
NONE = "none"
SIDES = ("source", "target")
TASK_ROLES = ("training", "target")

# specs loaded from files in this process, by name
_LOADED: dict[str, PairPreset] = {}
#: The spec files loaded in this process and its parents, in order (``os.pathsep``-joined
#: absolute paths): child processes inherit the environment, and read them on a miss.
SPEC_FILES_ENV = "PVED_SPEC_FILES"


def _remember(path: Path) -> None:
    files = [f for f in os.environ.get(SPEC_FILES_ENV, "").split(os.pathsep) if f]
    here = str(path.resolve())
    os.environ[SPEC_FILES_ENV] = os.pathsep.join([*(f for f in files if f != here), here])


def _inherited(name: str) -> PairPreset | None:
    """The spec named ``name`` among the files a parent process loaded (the last such)."""
    found = None
    for f in os.environ.get(SPEC_FILES_ENV, "").split(os.pathsep):
        if f and Path(f).is_file():
            preset = read_spec(Path(f))
            if preset.name == name:
                found = preset
    return found


def builtin_names() -> list[str]:
    """The names of the pairs shipped with pved, sorted."""
    return sorted(p.stem for p in PAIRS_DIR.glob("*.toml"))


@cache
def _builtin(name: str) -> PairPreset:
    return read_spec(PAIRS_DIR / f"{name}.toml")


def builtin_pairs() -> dict[str, PairPreset]:
    """Every built-in pair by name (a fresh dict; the presets are frozen)."""
    return {name: _builtin(name) for name in builtin_names()}


def _is_file_argument(pair: str) -> bool:
    return pair.endswith(".toml") or "/" in pair or "\\" in pair


def load_pair(pair: str | Path) -> PairPreset:
    """The pair ``pair``: a built-in name, the name of a spec loaded before in this
    process, or the path of a spec file (``*.toml``), which is then remembered under its
    name (the file read last, for a name two files share). A spec that takes a built-in
    pair's name must be that pair (run directories are kept under the name)."""
    text = str(pair)
    if not _is_file_argument(text):
        if text in builtin_names():
            return _builtin(text)
        if text in _LOADED:
            return _LOADED[text]
        inherited = _inherited(text)
        if inherited is not None:
            _LOADED[text] = inherited
            return inherited
        raise PvedError(
            f"unknown pair {text!r}; known pairs: {', '.join(builtin_names() + sorted(_LOADED))}"
            ", or a spec file (.toml)"
        )
    preset = read_spec(Path(text))
    if preset.name in builtin_names() and preset != _builtin(preset.name):
        field = _first_difference(preset, _builtin(preset.name))
        raise PvedError(
            f"spec {text}: name {preset.name!r} is a built-in pair's, but its {field} "
            "differs from it; give the spec another name"
        )
    # the file read last stands for its name (an edited spec read again replaces the
    # earlier one; what was made under that one is refused by its spec digest)
    _LOADED[preset.name] = preset
    _remember(Path(text))
    return preset


def preset_for_agent(agent: str) -> PairPreset:
    """The first pair in which ``agent`` takes part: the specs loaded from files first
    (so a user's agent named like a built-in one gets the user's PPO), then the
    built-in pairs in name order."""
    pairs = [*_LOADED.values(), *builtin_pairs().values()]
    for preset in pairs:
        if agent in (preset.source_agent, preset.target_agent):
            return preset
    agents = sorted({a for p in pairs for a in (p.source_agent, p.target_agent)})
    raise PvedError(f"unknown agent {agent!r}; known agents: {', '.join(agents)}")


def spec_identity(preset: PairPreset) -> dict[str, Any]:
    """The entry a stage adds to its run's config for a pair that is not a built-in one:
    a digest of what makes the pair (agents, tasks, envs and their arguments, robot
    state, task keys), so that a run directory, dataset, model or bank made under an
    earlier version of a spec is not taken for this one. Empty for a built-in pair, so
    the config hashes of the runs made before specs existed stand."""
    if preset.name in builtin_names() and preset == _builtin(preset.name):
        return {}
    what = {
        "agents": [preset.source_agent, preset.target_agent],
        "tasks": [preset.training_task, preset.target_task],
        "envs": [[e.agent, e.task, e.env_id, [list(kv) for kv in e.kwargs]] for e in preset.envs],
        "robot_state": [[a, list(i)] for a, i in preset.robot_state],
        "shared_task_keys": list(preset.shared_task_keys),
        "bank_match_keys": list(preset.bank_match_keys),
    }
    blob = json.dumps(what, sort_keys=True, default=str).encode()
    return {"spec": hashlib.sha256(blob).hexdigest()[:16]}


def _first_difference(a: PairPreset, b: PairPreset) -> str:
    for f in dataclasses.fields(a):
        if getattr(a, f.name) != getattr(b, f.name):
            return f.name
    return "content"


# ---------------------------------------------------------------------------- reading
class _Spec:
    """A spec file's table being read: each refusal is one line naming the file and the
    field, and every key must be known."""

    def __init__(self, path: Path, table: Mapping[str, Any], where: str = "") -> None:
        self.path, self.table, self.where = path, table, where
        self.used: set[str] = set()

    def fail(self, key: str, problem: str) -> PvedError:
        return PvedError(f"spec {self.path}: {self.where}{key} {problem}")

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = None) -> Any:
        self.used.add(key)
        if key not in self.table:
            if default is _REQUIRED:
                raise self.fail(key, "is missing")
            return default
        value = self.table[key]
        if not isinstance(value, kind) or (isinstance(value, bool) and bool not in _kinds(kind)):
            raise self.fail(key, f"must be {_kind_name(kind)}, not {value!r}")
        return value

    def sub(self, key: str, required: bool = False) -> _Spec:
        table = self.get(key, dict, _REQUIRED if required else {})
        return _Spec(self.path, table, f"{self.where}{key}.")

    def strings(self, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
        value = self.get(key, list, None)
        if value is None:
            return default
        if not all(isinstance(v, str) for v in value):
            raise self.fail(key, f"must be a list of strings, not {value!r}")
        return tuple(value)

    def done(self) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            known = ", ".join(sorted(self.used))
            raise self.fail(unknown[0], f"is not a spec field (known here: {known})")


_REQUIRED = object()


def _kinds(kind: type | tuple[type, ...]) -> tuple[type, ...]:
    return kind if isinstance(kind, tuple) else (kind,)


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {str: "a string", int: "an integer", float: "a number", bool: "true or false",
             list: "a list", dict: "a table"}  # fmt: skip
    return " or ".join(names.get(k, k.__name__) for k in _kinds(kind))


def _config(spec: _Spec, cls: type, base: Any = None, skip: tuple[str, ...] = ()) -> Any:
    """A config dataclass ``cls`` from ``spec``'s table: ``base`` (default: ``cls()``)
    with the fields the table gives; lists become tuples and ``"none"`` None. The
    dataclass checks its values (``pved.checks``); a refusal names the spec's field."""
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init and f.name not in skip}
    changes: dict[str, Any] = {}
    for key, value in spec.table.items():
        if key in skip:
            continue
        if key not in fields:
            raise spec.fail(key, f"is not a field of {cls.__name__} ({', '.join(fields)})")
        spec.used.add(key)
        if value == NONE:
            value = None
        elif isinstance(value, list):
            value = tuple(value)
        elif (
            isinstance(value, int)
            and not isinstance(value, bool)
            and "float" in str(fields[key].type)
        ):
            value = float(value)  # ``alpha3 = 10`` is 10.0: a config's hash tells them apart
        changes[key] = value
    try:
        return dataclasses.replace(base if base is not None else cls(), **changes)
    except PvedError as exc:
        raise PvedError(f"spec {spec.path}: {spec.where.rstrip('.')}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise PvedError(f"spec {spec.path}: {spec.where.rstrip('.')}: {exc}") from None


def _agent(spec: _Spec, side: str, tasks: tuple[str, str]) -> tuple[str, list[AgentEnv], Any]:
    table = spec.sub(side, required=True)
    agent = table.get("agent", str, _REQUIRED)
    robot_state = table.get("robot_state", list, None)
    if robot_state is not None and not all(
        isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in robot_state
    ):
        raise table.fail("robot_state", f"must be a list of indices >= 0, not {robot_state!r}")
    envs = []
    for role, task in zip(TASK_ROLES, tasks, strict=True):
        env = table.sub(role, required=True)
        env_id = env.get("env", str, _REQUIRED)
        kwargs = env.get("kwargs", dict, {})
        policy = env.get("policy", str, PRETRAINED if env_id.startswith("pved/") else TRAINED)
        if policy not in (PRETRAINED, TRAINED):
            # a path, from the spec file's directory; the file is looked for when used
            policy = str((spec.path.parent / policy).resolve())
        env.done()
        envs.append(AgentEnv(agent, task, env_id, tuple(sorted(kwargs.items())), policy))
    table.done()
    return agent, envs, None if robot_state is None else tuple(robot_state)


def read_spec(path: Path) -> PairPreset:
    """The :class:`PairPreset` a spec file says; every mistake is a one-line
    :class:`PvedError` naming the file and the field."""
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise PvedError(f"spec not found: {path}") from None
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PvedError(f"spec {path} is not readable TOML: {exc}") from None
    return parse_spec(data, Path(path))


def parse_spec(data: Mapping[str, Any], path: Path) -> PairPreset:
    """:func:`read_spec` of an already parsed TOML document (``path`` names it)."""
    top = _Spec(path, data)
    name = top.get("name", str, _REQUIRED)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise top.fail("name", f"must be letters, digits, '-', '_' or '.', not {name!r}")
    tasks = (top.get("training_task", str, _REQUIRED), top.get("target_task", str, _REQUIRED))
    if tasks[0] == tasks[1]:
        raise top.fail("target_task", "must differ from training_task")
    src, src_envs, src_state = _agent(top, "source", tasks)
    tgt, tgt_envs, tgt_state = _agent(top, "target", tasks)
    if src == tgt:
        raise top.fail("target.agent", "must differ from source.agent")
    defaults = PairPreset(name, src, tgt, tasks[0], tasks[1], PVEDConfig(), TransferConfig())

    task_keys = top.sub("tasks")
    shared = task_keys.strings("shared", defaults.shared_task_keys)
    bank_match = task_keys.strings("bank_match", defaults.bank_match_keys)
    task_keys.done()

    metric = top.sub("metric")
    metric_name = metric.get("name", str, defaults.metric)
    resolution = metric.get("resolution", (int, float, str), defaults.metric_resolution)
    resolution = None if resolution == NONE else resolution
    if isinstance(resolution, str):
        raise metric.fail("resolution", f"must be a number or {NONE!r}")
    info_keys = metric.strings("info_keys", defaults.eval_info_keys)
    in_reward = metric.get("in_target_reward", bool, defaults.metric_in_target_reward)
    metric.done()

    pairing = _config(top.sub("pairing"), PairingConfig)
    model = _config(top.sub("model"), PVEDConfig)
    transfer_spec = top.sub("transfer")
    transfer_ppo = _config(transfer_spec.sub("ppo"), PPOConfig)
    transfer = _config(transfer_spec, TransferConfig, TransferConfig(ppo=transfer_ppo), ("ppo",))
    transfer_spec.used.add("ppo")

    policy = top.sub("policy")
    policy_ppo = _config(policy.sub("ppo"), PPOConfig)
    overrides = []
    for k, entry in enumerate(policy.get("override", list, [])):
        if not isinstance(entry, dict):
            raise policy.fail(f"override[{k}]", "must be a table")
        over = _Spec(path, entry, f"{policy.where}override[{k}].")
        agent = over.get("agent", str, _REQUIRED)
        task = over.get("task", str, _REQUIRED)
        if agent not in (src, tgt) or task not in tasks:
            raise over.fail("agent", f"and task ({agent}, {task}) are not the pair's")
        overrides.append((agent, task, _config(over, PPOConfig, policy_ppo, ("agent", "task"))))
    keep_best = policy.get("keep_best", bool, defaults.policy_keep_best)
    eval_episodes = policy.get("eval_episodes", int, defaults.policy_eval_episodes)
    stop_completion = policy.get("stop_completion", (float, int, str), NONE)
    stop_evaluations = policy.get("stop_evaluations", int, defaults.policy_stop_evaluations)
    stop_gain = policy.get("stop_gain", (float, int), defaults.policy_stop_gain)
    policy.done()

    protocol = top.sub("protocol")
    grid = protocol.get("beta_grid", list, list(defaults.beta_grid))
    method_grids = protocol.get("method_beta_grids", dict, None)
    steps = protocol.get("steps", dict, None)
    protocol.done()

    state = tuple((a, s) for a, s in ((src, src_state), (tgt, tgt_state)) if s is not None)
    top.done()
    try:
        return PairPreset(
            name=name,
            source_agent=src,
            target_agent=tgt,
            training_task=tasks[0],
            target_task=tasks[1],
            model=model,
            transfer=transfer,
            pairing=pairing,
            shared_task_keys=shared,
            bank_match_keys=bank_match,
            metric=metric_name,
            metric_resolution=None if resolution is None else float(resolution),
            eval_info_keys=info_keys,
            metric_in_target_reward=in_reward,
            policy=policy_ppo,
            policy_overrides=tuple(overrides),
            policy_keep_best=keep_best,
            policy_eval_episodes=eval_episodes,
            policy_stop_completion=None if stop_completion == NONE else float(stop_completion),
            policy_stop_evaluations=stop_evaluations,
            policy_stop_gain=float(stop_gain),
            beta_grid=tuple(float(b) for b in grid),
            method_beta_grids=(
                defaults.method_beta_grids
                if method_grids is None
                else tuple((m, tuple(float(b) for b in g)) for m, g in method_grids.items())
            ),
            protocol_steps=(
                defaults.protocol_steps
                if steps is None
                else tuple((b, int(n)) for b, n in steps.items())
            ),
            envs=(*src_envs, *tgt_envs),
            robot_state=state,
        )
    except (TypeError, ValueError) as exc:
        raise PvedError(f"spec {path}: {exc}") from None


# ---------------------------------------------------------------------------- writing
def toml_value(value: Any) -> str:
    """``value`` (None, bool, number, str, list, mapping) as a TOML value, as spec files
    and pre-registrations (:mod:`pved.protocol.choose`) write them."""
    if value is None:
        return json.dumps(NONE)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if value == value and abs(value) != float("inf") else str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {toml_value(v)}" for k, v in value.items()) + " }"
    raise PvedError(f"cannot write {value!r} to a spec")


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _changes(value: Any, base: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """The init fields of dataclass ``value`` that differ from ``base``'s."""
    return {
        f.name: getattr(value, f.name)
        for f in dataclasses.fields(value)
        if f.init and f.name not in skip and getattr(value, f.name) != getattr(base, f.name)
    }


def dump_pair(preset: PairPreset) -> str:
    """The spec file of ``preset``: every field that differs from its default, so that
    ``read_spec`` of the text gives ``preset`` back (``pved pair show``)."""
    lines = [
        "# pved pair spec (docs/pairs.md); `pved pair check` this file after editing it",
        f"name = {toml_value(preset.name)}",
        f"training_task = {toml_value(preset.training_task)}",
        f"target_task = {toml_value(preset.target_task)}",
    ]

    def table(header: str, values: Mapping[str, Any]) -> None:
        lines.append("")
        lines.append(f"[{header}]")
        lines.extend(f"{_key(k)} = {toml_value(v)}" for k, v in values.items())

    for side, agent in zip(SIDES, (preset.source_agent, preset.target_agent), strict=True):
        head: dict[str, Any] = {"agent": agent}
        state = preset.robot_state_of(agent)
        if state is not None:
            head["robot_state"] = list(state)
        table(side, head)
        for role, task in zip(TASK_ROLES, (preset.training_task, preset.target_task), strict=True):
            env = preset.agent_env(agent, task)
            values: dict[str, Any] = {"env": env.env_id}
            if env.kwargs:
                values["kwargs"] = dict(env.kwargs)
            default_policy = PRETRAINED if env.env_id.startswith("pved/") else TRAINED
            if env.policy != default_policy:
                values["policy"] = env.policy
            table(f"{side}.{role}", values)
    table(
        "tasks",
        {"shared": list(preset.shared_task_keys), "bank_match": list(preset.bank_match_keys)},
    )
    table(
        "metric",
        {
            "name": preset.metric,
            "resolution": preset.metric_resolution,
            "info_keys": list(preset.eval_info_keys),
            "in_target_reward": preset.metric_in_target_reward,
        },
    )
    table("pairing", _changes(preset.pairing, PairingConfig()))
    table("model", _changes(preset.model, PVEDConfig()))
    table("transfer", _changes(preset.transfer, TransferConfig(), ("ppo",)))
    table("transfer.ppo", _changes(preset.transfer.ppo, PPOConfig()))
    table(
        "policy",
        {
            "keep_best": preset.policy_keep_best,
            "eval_episodes": preset.policy_eval_episodes,
            "stop_completion": preset.policy_stop_completion,
            "stop_evaluations": preset.policy_stop_evaluations,
            "stop_gain": preset.policy_stop_gain,
        },
    )
    table("policy.ppo", _changes(preset.policy, PPOConfig()))
    for agent, task, cfg in preset.policy_overrides:
        lines.append("")
        lines.append("[[policy.override]]")
        over = {"agent": agent, "task": task, **_changes(cfg, preset.policy)}
        lines.extend(f"{_key(k)} = {toml_value(v)}" for k, v in over.items())
    table(
        "protocol",
        {
            "beta_grid": list(preset.beta_grid),
            "method_beta_grids": {m: list(g) for m, g in preset.method_beta_grids},
            "steps": dict(preset.protocol_steps),
        },
    )
    return "\n".join(lines) + "\n"


def get_preset(pair: str | Path) -> PairPreset:
    """The pair ``pair`` (:func:`load_pair`): the name every stage looks a pair up by."""
    return load_pair(pair)


def __getattr__(name: str) -> Any:
    # ``PRESETS``: the built-in pairs, read from their spec files when first asked for
    # (pved/pairs/*.toml), so that importing this module reads no file
    if name == "PRESETS":
        return builtin_pairs()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
