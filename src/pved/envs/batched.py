"""Shared machinery of MuJoCo-batched pved environments and their Gymnasium adapter.

:class:`MujocoBatchedEnv` holds N ``mujoco.MjData`` of one ``MjModel``. Physics is one
``mujoco.mj_step(model, data, nstep=frame_skip)`` call per copy (MuJoCo's C engine does
the work; the Python loop around it costs little next to it); everything else is numpy
over the batch: state is gathered into (N, nq) / (N, nv) arrays once per step, and a
task subclass computes observations, rewards, terminations and resets from them.

Randomness: copy ``i`` owns its ``np.random.Generator``, seeded with ``seed + i`` on
``reset(seed=seed)``. A reset draws one fixed-size block of uniforms per resetting copy
(the only per-copy call), and the task turns the (k, n) block into initial states and
task parameters with vectorised numpy. Because the block has the same size whether or
not reset options fix some parameters, copy ``i`` of a batch and a single env seeded
``seed + i`` consume their streams identically, so the two give identical transitions.

:class:`BatchOfOneEnv` is the plain ``gymnasium.Env``: a batch of one without autoreset,
plus offscreen ``rgb_array`` rendering through ``mujoco.Renderer``.

What every pair's envs share beyond the machinery lives here too: the reward-mode rule
(:func:`select_reward_terms`) and the config check (:func:`resolve_config`). The arms of
hinge joints of the Reacher and robot-arm pairs share more, in :mod:`pved.envs.hinge_arm`.
"""

from __future__ import annotations

import os
from abc import abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar

import gymnasium as gym
import mujoco
import numpy as np

from pved.envs.base import BatchedEnv, Info
from pved.errors import PvedError

ASSETS_DIR = Path(__file__).resolve().parent / "assets"
# Everything MuJoCo needs to continue a simulation exactly (state, controls, warm start).
_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
#: The ``reward`` modes every pair's envs take (:func:`select_reward_terms`).
REWARD_MODES = ("default", "restricted", "full")


def load_model(filename: str) -> mujoco.MjModel:
    """Compile the MJCF file ``filename`` of ``pved/envs/assets``."""
    path = ASSETS_DIR / filename
    if not path.is_file():
        raise PvedError(f"missing MJCF asset {path}")
    return mujoco.MjModel.from_xml_path(str(path))


def split_reward_terms(
    terms: dict[str, np.ndarray], used: tuple[str, ...], num_envs: int
) -> tuple[np.ndarray, Info]:
    """The reward (N,) as the sum of the ``used`` terms, and the ``info`` entries of every
    term: ``reward_<name>`` for those summed (in ``used`` order) and ``metric_<name>`` for
    the others, so that the ``reward_*`` entries always add up to the reward."""
    info: Info = {}
    reward = np.zeros(num_envs)
    for name in used:
        info[f"reward_{name}"] = terms[name]
        reward = reward + terms[name]
    for name, value in terms.items():
        if name not in used:
            info[f"metric_{name}"] = value
    return reward, info


def select_reward_terms(
    reward: str,
    task: str,
    tasks: tuple[str, str],
    family: str,
    target_agent: bool,
    full: tuple[str, ...],
    restricted: tuple[str, ...],
) -> tuple[str, ...]:
    """The reward terms summed under ``reward`` mode, by the rule every pair shares.

    Args:
        reward: "default", "restricted" or "full" (``REWARD_MODES``).
        task: the task; ``tasks`` = (training task, target task) of the pair.
        family: the envs' name in the unknown-task error ("arm", "Reacher", ...).
        target_agent: whether the agent is the pair's target agent.
        full: the agent's full reward on ``task``; restricted: the paper's target-task
            reward (used on the target task only).

    ``"full"`` sums ``full``; ``"restricted"``, which exists only on the target task,
    sums ``restricted``; ``"default"`` is restricted for the target agent on the target
    task and full otherwise.
    """
    if reward not in REWARD_MODES:
        raise PvedError(f"unknown reward {reward!r}; known: {', '.join(REWARD_MODES)}")
    if task not in tasks:
        raise PvedError(f"unknown {family} task {task!r}; known tasks: {', '.join(tasks)}")
    training_task, target_task = tasks
    if task == training_task:
        if reward == "restricted":
            raise PvedError(
                f"reward 'restricted' exists only for {target_task}; "
                f"{training_task} takes 'default'/'full'"
            )
        return full
    if reward == "default":
        reward = "restricted" if target_agent else "full"
    return restricted if reward == "restricted" else full


class _AgentConfig(Protocol):
    @property
    def agent(self) -> str: ...


_Config = TypeVar("_Config", bound=_AgentConfig)


def resolve_config(
    agent: str,
    task: str,
    config: object | None,
    expected: type[_Config],
    default: Callable[[str, str], object],
) -> _Config:
    """``config``, or ``default(agent, task)`` when it is None, checked to be an
    ``expected`` (the task's config class) for ``agent``."""
    cfg = default(agent, task) if config is None else config
    if not isinstance(cfg, expected):
        name = expected.__name__
        article = "an" if name[0] in "AEIOU" else "a"
        raise PvedError(f"config for {task} must be {article} {name}")
    if cfg.agent != agent:
        raise PvedError(f"config is for agent {cfg.agent!r}, not {agent!r}")
    return cfg


def joint_addresses(model: mujoco.MjModel, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The qpos and dof addresses, (n,) int64 each, of the joints ``names`` of ``model``."""
    ids = [model.joint(name).id for name in names]
    qpos_adr = np.asarray(model.jnt_qposadr[ids], dtype=np.int64)
    dof_adr = np.asarray(model.jnt_dofadr[ids], dtype=np.int64)
    return qpos_adr, dof_adr


def _check_num_envs(num_envs: int) -> int:
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
        raise PvedError(f"num_envs must be a positive integer, got {num_envs!r}")
    return int(num_envs)


class MujocoBatchedEnv(BatchedEnv):
    """N copies of one MuJoCo model; a task subclass supplies the task logic.

    Subclasses set ``single_observation_space`` and ``observation_names`` (e.g. with
    :meth:`_set_observation_names`) and ``robot_state_indices``, and implement the hooks
    ``_num_reset_uniforms``, ``_initial_state``, ``_observe``, ``_evaluate``,
    ``_reset_info`` and ``_task_params``. State arrays kept up to date after every step and reset:

    Attributes:
        model: the shared ``mujoco.MjModel``.
        datas: N ``mujoco.MjData``, one per copy.
        qpos: (N, nq) float64 joint positions.
        qvel: (N, nv) float64 joint velocities.
        elapsed_steps: (N,) int64 control steps taken in each copy's current episode.
        dt: control period in seconds (``timestep * frame_skip``).
        task_param_keys: the ``info`` keys holding task parameters (set by the task).
        autoreset: whether ``step`` resets finished copies (True for the batched form).
        observation_names: the name of every observation entry (set by the task).
    """

    observation_names: tuple[str, ...]

    def __init__(
        self,
        model: mujoco.MjModel,
        num_envs: int,
        frame_skip: int,
        max_episode_steps: int,
        autoreset: bool = True,
    ) -> None:
        self.num_envs = _check_num_envs(num_envs)
        if frame_skip < 1:
            raise PvedError(f"frame_skip must be >= 1, got {frame_skip}")
        if max_episode_steps < 1:
            raise PvedError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.model = model
        self.datas = [mujoco.MjData(model) for _ in range(self.num_envs)]
        self.frame_skip = int(frame_skip)
        self.dt = float(model.opt.timestep) * self.frame_skip
        self.max_episode_steps = int(max_episode_steps)
        self.autoreset = autoreset
        self.qpos = np.zeros((self.num_envs, model.nq))
        self.qvel = np.zeros((self.num_envs, model.nv))
        self.elapsed_steps = np.zeros(self.num_envs, dtype=np.int64)
        ctrl_range = np.asarray(model.actuator_ctrlrange, dtype=np.float64)
        self._act_low = ctrl_range[:, 0].copy()
        self._act_high = ctrl_range[:, 1].copy()
        self.single_action_space = gym.spaces.Box(
            low=self._act_low.astype(np.float32),
            high=self._act_high.astype(np.float32),
            dtype=np.float32,
        )
        self.task_param_keys: tuple[str, ...] = ()
        self.rngs: list[np.random.Generator] | None = None
        self._has_reset = False

    # ------------------------------------------------------------------ task hooks
    @property
    @abstractmethod
    def _num_reset_uniforms(self) -> int:
        """How many U[0, 1) numbers one copy draws per reset (a constant)."""

    @abstractmethod
    def _initial_state(
        self, idx: np.ndarray, uniforms: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw the task parameters and initial state of copies ``idx`` (k,).

        Args:
            idx: (k,) indices of the copies being reset.
            uniforms: (k, _num_reset_uniforms) U[0, 1) draws, row j for copy idx[j].
            options: ``reset`` options already validated, arrays with leading axis N
                (None at autoreset).

        Returns:
            qpos (k, nq) and qvel (k, nv). The subclass stores its task parameters itself.
        """

    @abstractmethod
    def _observe(self) -> np.ndarray:
        """(N, obs_dim) float64 observations of the current state."""

    @abstractmethod
    def _evaluate(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, Info]:
        """Reward (N,), terminated (N,) bool and the step quantities (reward terms,
        ``is_success``, state readouts) of the transition just simulated."""

    @abstractmethod
    def _reset_info(self) -> Info:
        """Step quantities that make sense at reset (``is_success``, readouts)."""

    @abstractmethod
    def _task_params(self) -> Info:
        """Task parameters of each copy's current episode, leading axis N; their keys
        are ``task_param_keys``."""

    def _validate_options(self, options: dict[str, Any]) -> dict[str, np.ndarray]:
        """Check ``reset`` options; return them as arrays with leading axis N."""
        if options:
            raise PvedError(f"unknown reset option(s) {sorted(options)}; this env takes none")
        return {}

    def _write_extra(self, i: int, data: mujoco.MjData) -> None:
        """Write non-joint state (e.g. mocap bodies) of copy ``i`` at reset; default none."""

    def _derive(self, idx: np.ndarray | slice) -> None:
        """Recompute quantities derived from ``qpos``/``qvel`` (end effector...) for the
        copies ``idx`` after their state changed; default none."""

    # ------------------------------------------------------------------ contract
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        """Reset every copy; copy ``i`` is seeded ``seed + i`` when ``seed`` is given.

        Returns:
            obs: (N, obs_dim) float64; info: task parameters etc., leading axis N.
        """
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
                raise PvedError(f"seed must be a non-negative integer, got {seed!r}")
            self.rngs = [np.random.default_rng(int(seed) + i) for i in range(self.num_envs)]
        elif self.rngs is None:
            # Unseeded first reset: independent fresh streams for the copies.
            children = np.random.SeedSequence().spawn(self.num_envs)
            self.rngs = [np.random.default_rng(child) for child in children]
        checked = self._validate_options(dict(options)) if options else None
        self._reset_copies(np.arange(self.num_envs), checked)
        self._has_reset = True
        info = self._reset_info()
        info.update(self._task_params())
        return self._observe(), info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        """Apply ``actions`` (N, act_dim) for ``frame_skip`` physics steps per copy.

        Actions are clipped to the actuators' control range (the reward's control cost
        sees the clipped action). With ``autoreset``, finished copies are reset here and
        ``info["final_obs"]`` (N, obs_dim) holds each copy's observation before any reset
        (equal to the returned one for copies that did not finish). Step quantities in
        ``info`` (reward terms, ``is_success``, readouts such as ``ee_pos``) describe the
        transition just taken; the task parameters (``task_param_keys``) describe the
        episode the returned observation belongs to, i.e. the new one after an autoreset
        (``base.py``).

        Returns:
            obs (N, obs_dim), reward (N,), terminated (N,) bool, truncated (N,) bool, info.
        """
        if not self._has_reset:
            raise PvedError("call reset() before step()")
        act = np.asarray(actions, dtype=np.float64)
        expected = (self.num_envs, self.single_action_space.shape[0])
        if act.shape != expected:
            raise PvedError(f"actions must have shape {expected}, got {act.shape}")
        if not np.isfinite(act).all():
            raise PvedError("actions contain NaN or infinity")
        act = np.clip(act, self._act_low, self._act_high)
        model, nstep = self.model, self.frame_skip
        for i, data in enumerate(self.datas):
            data.ctrl[:] = act[i]
            mujoco.mj_step(model, data, nstep=nstep)
            self.qpos[i] = data.qpos
            self.qvel[i] = data.qvel
        self._derive(slice(None))
        self.elapsed_steps += 1
        reward, terminated, info = self._evaluate(act)
        obs = self._observe()
        truncated = (self.elapsed_steps >= self.max_episode_steps) & ~terminated
        if self.autoreset:
            info["final_obs"] = obs.copy()
            done = np.flatnonzero(terminated | truncated)
            if done.size:
                self._reset_copies(done, None)
                obs[done] = self._observe()[done]
        info.update(self._task_params())
        return obs, reward, terminated, truncated, info

    def state_dict(self) -> dict[str, Any]:
        """Everything a later :meth:`load_state_dict` needs to continue bit-exactly:
        MuJoCo's integration state of every copy (warm start included), episode counters,
        generators and the task's own state. PPO puts it into its checkpoints (the names
        are the ones ``pved.rl.ppo`` looks for), so a resumed run continues the same
        episodes."""
        size = mujoco.mj_stateSize(self.model, _STATE_SPEC)
        states = np.zeros((self.num_envs, size))
        for i, data in enumerate(self.datas):
            mujoco.mj_getState(self.model, data, states[i], _STATE_SPEC)
        return {
            "mj_state": states,
            "elapsed_steps": self.elapsed_steps.copy(),
            "rng": None if self.rngs is None else [r.bit_generator.state for r in self.rngs],
            "has_reset": self._has_reset,
            "task": self._get_task_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict` of an env built with the same arguments."""
        size = mujoco.mj_stateSize(self.model, _STATE_SPEC)
        states = np.asarray(state["mj_state"], dtype=np.float64)
        if states.shape != (self.num_envs, size):
            raise PvedError(f"env state has shape {states.shape}, expected {(self.num_envs, size)}")
        for i, data in enumerate(self.datas):
            # No mj_forward: it is not needed (mj_step recomputes everything) and the
            # restored warm start must be what the next step starts from.
            mujoco.mj_setState(self.model, data, states[i], _STATE_SPEC)
            self.qpos[i] = data.qpos
            self.qvel[i] = data.qvel
        self.elapsed_steps = np.asarray(state["elapsed_steps"], dtype=np.int64).copy()
        if state["rng"] is None:
            self.rngs = None
        else:
            self.rngs = [np.random.default_rng() for _ in range(self.num_envs)]
            for rng, rng_state in zip(self.rngs, state["rng"], strict=True):
                rng.bit_generator.state = rng_state
        self._has_reset = bool(state["has_reset"])
        self._set_task_state(state["task"])
        self._derive(slice(None))

    def _get_task_state(self) -> dict[str, np.ndarray]:
        """The task's own mutable arrays (task parameters, counters); default none."""
        return {}

    def _set_task_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`_get_task_state`; default none."""

    def set_joint_state(
        self, qpos: np.ndarray, qvel: np.ndarray, indices: np.ndarray | None = None
    ) -> None:
        """Overwrite the joint state of copies ``indices`` (default all) without touching
        task parameters or episode counters (for tests and scripted demonstrations).

        Args:
            qpos: (k, nq); qvel: (k, nv), k = len(indices).
        """
        idx = np.arange(self.num_envs) if indices is None else np.asarray(indices, dtype=int)
        qpos = np.asarray(qpos, dtype=np.float64).reshape(len(idx), self.model.nq)
        qvel = np.asarray(qvel, dtype=np.float64).reshape(len(idx), self.model.nv)
        for j, i in enumerate(idx):
            data = self.datas[i]
            data.qpos[:] = qpos[j]
            data.qvel[:] = qvel[j]
            mujoco.mj_forward(self.model, data)
        self.qpos[idx] = qpos
        self.qvel[idx] = qvel
        self._derive(idx)

    # ------------------------------------------------------------------ internals
    def _reset_copies(self, idx: np.ndarray, options: dict[str, np.ndarray] | None) -> None:
        assert self.rngs is not None
        uniforms = np.stack([self.rngs[i].random(self._num_reset_uniforms) for i in idx])
        qpos, qvel = self._initial_state(idx, uniforms, options)
        for j, i in enumerate(idx):
            data = self.datas[i]
            # A full reset clears warm starts and contacts, so a copy's new episode does
            # not depend on how its previous one ended (and equals a fresh single env).
            mujoco.mj_resetData(self.model, data)
            data.qpos[:] = qpos[j]
            data.qvel[:] = qvel[j]
            self._write_extra(int(i), data)
            mujoco.mj_forward(self.model, data)
        self.qpos[idx] = qpos
        self.qvel[idx] = qvel
        self._derive(idx)
        self.elapsed_steps[idx] = 0

    def _set_observation_names(self, names: tuple[str, ...]) -> None:
        """Set ``observation_names`` and the unbounded float64 ``single_observation_space``
        of that many entries."""
        self.observation_names = names
        dim = len(names)
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (dim,), np.float64)

    def _batched_option(self, name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
        """``value`` as an (N, *shape) float64 array; a single (*shape) value is
        broadcast to every copy."""
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape == shape:
            arr = np.broadcast_to(arr, (self.num_envs, *shape))
        if arr.shape != (self.num_envs, *shape):
            raise PvedError(
                f"reset option {name!r} must have shape {(self.num_envs, *shape)} "
                f"or {shape}, got {arr.shape}"
            )
        if not np.isfinite(arr).all():
            raise PvedError(f"reset option {name!r} contains NaN or infinity")
        return np.array(arr)


def _unbatch(info: Info) -> dict[str, Any]:
    """Row 0 of every batched info entry (the single env's info)."""
    return {key: value[0] for key, value in info.items()}


class BatchOfOneEnv(gym.Env[np.ndarray, np.ndarray]):
    """The ``gymnasium.Env`` form of a task: a batch of one without autoreset.

    Transitions are the batch's by construction. ``render_mode="rgb_array"`` renders
    offscreen (``MUJOCO_GL=osmesa`` or ``egl`` on headless machines) from the model's
    camera ``camera``; rendering uses a scratch ``MjData`` so it never perturbs the
    simulation.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        batched: MujocoBatchedEnv,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
        camera: str = "top",
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise PvedError(f"unknown render_mode {render_mode!r}; known: 'rgb_array'")
        if batched.num_envs != 1 or batched.autoreset:
            raise PvedError("BatchOfOneEnv needs a batch of one without autoreset")
        self.batched = batched
        self.observation_space = batched.single_observation_space
        self.action_space = batched.single_action_space
        self.robot_state_indices = batched.robot_state_indices
        self.max_episode_steps = batched.max_episode_steps
        self.render_mode = render_mode
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": round(1.0 / batched.dt)}
        self._width, self._height, self._camera = int(width), int(height), camera
        self._renderer: mujoco.Renderer | None = None
        self._scratch: mujoco.MjData | None = None
        # Every task names its observation entries; the plain env shows them too.
        self.observation_names = batched.observation_names

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset; ``options`` take single values (e.g. ``target`` of shape (2,))."""
        super().reset(seed=seed)
        batch_options = None
        if options:
            batch_options = {k: np.asarray(v, dtype=np.float64)[None] for k, v in options.items()}
        obs, info = self.batched.reset(seed=seed, options=batch_options)
        # The env's np_random is the stream the batch copy actually draws from.
        assert self.batched.rngs is not None
        self._np_random = self.batched.rngs[0]
        return obs[0], _unbatch(info)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One control step of action (act_dim,); truncates at ``max_episode_steps``."""
        act = np.asarray(action, dtype=np.float64)
        if act.shape != self.action_space.shape:
            raise PvedError(f"action must have shape {self.action_space.shape}, got {act.shape}")
        obs, reward, terminated, truncated, info = self.batched.step(act[None])
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), _unbatch(info)

    def set_joint_state(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Overwrite the joint state: qpos (nq,), qvel (nv,) (tests, scripted demos)."""
        self.batched.set_joint_state(np.asarray(qpos)[None], np.asarray(qvel)[None])

    def render(self) -> np.ndarray | None:
        """(height, width, 3) uint8 image of the current state, or None without a mode."""
        if self.render_mode is None:
            return None
        model = self.batched.model
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(model, height=self._height, width=self._width)
            except mujoco.FatalError as err:
                # without a display MuJoCo's default GL backend has no context to open
                raise PvedError(
                    f"cannot render: {err}; on a machine without a display set "
                    f"MUJOCO_GL=osmesa or egl (MUJOCO_GL is {os.environ.get('MUJOCO_GL')!r})"
                ) from None
            self._scratch = mujoco.MjData(model)
        assert self._scratch is not None
        live = self.batched.datas[0]
        self._scratch.qpos[:] = live.qpos
        self._scratch.qvel[:] = live.qvel
        if model.nmocap:
            self._scratch.mocap_pos[:] = live.mocap_pos
            self._scratch.mocap_quat[:] = live.mocap_quat
        mujoco.mj_forward(model, self._scratch)
        self._renderer.update_scene(self._scratch, camera=self._camera)
        return self._renderer.render()

    def close(self) -> None:
        """Free the renderer (safe to call twice)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
            self._scratch = None
