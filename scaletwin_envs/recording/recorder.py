"""Record an episode of any loader env instance (made with ``gym.make`` or directly, model altered or not).

:class:`EpisodeRecorder` is an ``on_step`` callback (the contract of :func:`scaletwin_envs.rollout.run_episode`):
it reads the commands, ``info`` and the joint states of the env's MuJoCo data at every step, and builds a
:class:`~scaletwin_envs.recording.recording.Recording` at the end. :func:`record_episode` runs a policy with it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import math
import secrets
from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pandas as pd

import scaletwin_envs
from scaletwin_envs.recording.recording import Provenance, Recording
from scaletwin_envs.recording.schema import COMMAND_COLUMNS, EPISODE_NUMERIC, TRUCK_UNITS, column_units, joint_units
from scaletwin_envs.signal_units import SIGNAL_UNITS

StepCallback = Callable[[int, np.ndarray, dict[str, Any]], None]
#: Constructor arguments kept out of ``env_kwargs``: resolved into ``machine``/``soil``, or not physics.
RESOLVED_KWARGS = frozenset({"scale", "law", "distortion", "soil", "render_mode", "width", "height"})
_NAN = math.nan


class EpisodeRecorder:
    """Collects one row per control step; call :meth:`recording` when the episode is over.

    Args:
        env: the env (any wrapper around a loader env); its MuJoCo model may have been altered.
        seed: the seed the episode was reset with (stored in the provenance).
        policy: a description of what produced the commands.

    The callback must see the reset (step 0, not a row) before the first step. Made before that reset, it switches
    the env's second route to the pin forces on (``*_route2``, ``residual_*`` columns) unless the env was made with
    ``two_route_check=False``.
    """

    def __init__(self, env: gym.Env, seed: int | None = None, policy: str = "unknown") -> None:
        self.env, self.unwrapped = env, env.unwrapped
        self.seed, self.policy = seed, policy
        model = self.unwrapped.model
        self.joints = joint_units(model)
        # joint_units orders the columns q_<j>, qd_<j> per joint: gather qpos and qvel in that order
        self._q = np.array([model.jnt_qposadr[j] for j in range(model.njnt)], dtype=np.intp)
        self._qd = np.array([model.jnt_dofadr[j] for j in range(model.njnt)], dtype=np.intp)
        self._signals = tuple(SIGNAL_UNITS)
        self._rows: list[list[float]] = []
        self._states: list[np.ndarray] = []
        self._phases: list[str] = []
        self._model_sha256: str | None = None
        self._last_info: Mapping[str, Any] = {}
        self._truck: tuple[str, ...] = ()  # TRUCK_UNITS columns this env reports (set at the reset)
        request = getattr(self.unwrapped, "request_two_route_check", None)
        if request is not None:  # a recording carries both routes unless the env was made without route 2
            request()

    def __call__(self, step: int, action: np.ndarray, info: dict[str, Any]) -> None:
        if step == 0:
            self._model_sha256 = model_fingerprint(self.unwrapped.model)
            self._truck = tuple(k for k in TRUCK_UNITS if k in info)
            return
        sig = info.get("signals", {})
        if not self._rows:
            _check_signal_units(sig)
        data = self.unwrapped.data
        t = float(info.get("time", step * self.unwrapped.dt))
        reward = sum(info["reward_terms"].values()) if info.get("reward_terms") else _NAN
        row = [float(step), t, *map(float, action), *(sig.get(k, _NAN) for k in self._signals),
               info.get("fill_factor", _NAN), info.get("spilled_mass", _NAN), info.get("hydraulic_work", _NAN),
               float(reward), *(float(info.get(k, _NAN)) for k in self._truck)]
        self._rows.append(row)
        self._states.append(np.column_stack((data.qpos[self._q], data.qvel[self._qd])).ravel())
        self._phases.append(str(info.get("phase", "")))
        self._last_info = info

    def recording(self) -> Recording:
        """The recording of the steps seen so far."""
        units = {**column_units(self.joints), **{k: TRUCK_UNITS[k] for k in self._truck}}
        numeric = ("step", "time", *COMMAND_COLUMNS, *self._signals, *EPISODE_NUMERIC, *self._truck)
        table = np.asarray(self._rows, dtype=np.float64).reshape(len(self._rows), len(numeric))
        states = np.asarray(self._states, dtype=np.float64).reshape(len(self._states), len(self.joints))
        cols: dict[str, Any] = dict(zip(numeric, table.T, strict=True))
        cols.update(zip(self.joints, states.T, strict=True))
        cols["step"] = cols["step"].astype(np.int64)
        cols["phase"] = pd.array(self._phases, dtype="str")
        frame = pd.DataFrame({c: cols[c] for c in units})
        return Recording(frame, units, self.provenance())

    def provenance(self) -> Provenance:
        """Provenance of this episode (machine, soil, seed, timing, env arguments, versions, model hash)."""
        extra: dict[str, Any] = {}
        if self._last_info.get("sim_error"):
            extra["sim_error"] = str(self._last_info["sim_error"])
        return env_provenance(self.env, self.seed, self.policy, self._model_sha256, extra)


def env_provenance(env: gym.Env, seed: int | None, policy: str = "unknown", model_sha256: str | None = None,
                   extra: Mapping[str, Any] | None = None) -> Provenance:
    """Provenance of an episode of ``env`` (``model_sha256`` defaults to the model as it is now)."""
    u = env.unwrapped
    return Provenance(
        machine=u.loader.to_dict() if hasattr(u, "loader") else None,
        soil=u.soil.to_dict() if hasattr(u, "soil") else None,
        seed=seed, timestep=float(u.model.opt.timestep), frame_skip=int(u.frame_skip), control_dt=float(u.dt),
        env_id=_env_id(env), env_kwargs=env_kwargs(env), policy=policy, package_version=scaletwin_envs.__version__,
        mujoco_version=mujoco.__version__, model_sha256=model_sha256 or model_fingerprint(u.model),
        source="simulation", extra=dict(extra or {}),
    )


def record_episode(env: gym.Env, policy: Any, seed: int | None = None, *, max_steps: int | None = None,
                   on_step: StepCallback | None = None, policy_name: str | None = None) -> Recording:
    """Run ``policy`` for one episode of ``env`` and record it.

    Args:
        env: any loader env instance (``gym.make`` or direct; its MuJoCo model may have been altered).
        policy: a callable obs → action, or anything with Stable-Baselines3's ``predict``; ``reset()`` is
            called first if it has one.
        seed: reset seed; None draws one, which is stored, so every recording can be replayed.
        max_steps: stop after this many control steps even if the episode has not ended.
        on_step: another callback to run at every step (e.g. a :class:`~.rerun_log.RerunLogger`).
        policy_name: stored in the provenance (default: the policy's repr for dataclasses, else its type).
    """
    seed = secrets.randbits(31) if seed is None else int(seed)
    recorder = EpisodeRecorder(env, seed, policy_name or describe_policy(policy))
    callbacks = [recorder] if on_step is None else [recorder, on_step]
    act = _action_fn(policy)
    if hasattr(policy, "reset"):
        policy.reset()
    obs, info = env.reset(seed=seed)
    for cb in callbacks:
        cb(0, np.zeros(env.action_space.shape), info)
    step, done = 0, False
    while not done and (max_steps is None or step < max_steps):
        action = np.asarray(act(obs), dtype=np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        step += 1
        for cb in callbacks:
            cb(step, action, info)
        done = terminated or truncated
    return recorder.recording()


def model_fingerprint(model: mujoco.MjModel) -> str:
    """SHA-256 of the compiled model (MJB bytes): equal for the twin and an unaltered env after reset."""
    buf = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return hashlib.sha256(buf.tobytes()).hexdigest()


def describe_policy(policy: Any) -> str:
    """A deterministic description: a dataclass's repr (its parameters), else its type's qualified name."""
    if dataclasses.is_dataclass(policy) and not isinstance(policy, type):
        return repr(policy)
    kind = policy if inspect.isfunction(policy) else type(policy)
    return f"{kind.__module__}.{kind.__qualname__}"


def env_kwargs(env: gym.Env) -> dict[str, Any]:
    """Constructor arguments of the env other than :data:`RESOLVED_KWARGS`, as JSON values.

    Read from the unwrapped env's attributes (every argument the constructor stores under its own name, and
    reward weights ``<key>_..._weight`` from ``weights[<key>]``), overridden by ``env.spec.kwargs`` when the env
    was made with ``gym.make``.
    """
    u = env.unwrapped
    out: dict[str, Any] = {}
    for name in inspect.signature(type(u).__init__).parameters:
        if name in RESOLVED_KWARGS or name == "self":
            continue
        if hasattr(u, name):
            out[name] = getattr(u, name)
        elif name.endswith("_weight") and name.split("_")[0] in getattr(u, "weights", {}):
            out[name] = u.weights[name.split("_")[0]]
    spec = getattr(env, "spec", None)
    if spec is not None:
        out.update({k: v for k, v in spec.kwargs.items() if k not in RESOLVED_KWARGS})
    return {k: _jsonable(v) for k, v in out.items()}


def _jsonable(value: Any) -> Any:
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "to_dict"):
        return _jsonable(value.to_dict())
    return repr(value)


def _env_id(env: gym.Env) -> str | None:
    spec = getattr(env, "spec", None) or getattr(env.unwrapped, "spec", None)
    if spec is not None:
        return spec.id
    from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv

    return scaletwin_envs.ENV_ID if type(env.unwrapped) is WheelLoaderDigEnv else None


def _check_signal_units(signals: Mapping[str, float]) -> None:
    unknown = sorted(set(signals) - set(SIGNAL_UNITS))
    if unknown:
        raise ValueError(f"signals {unknown} have no unit; add them to scaletwin_envs.signal_units.SIGNAL_UNITS "
                         f"(known: {sorted(SIGNAL_UNITS)})")


def _action_fn(policy: Any) -> Callable[[np.ndarray], np.ndarray]:
    if hasattr(policy, "predict") and not hasattr(policy, "act"):
        return lambda obs: policy.predict(obs, deterministic=True)[0]
    return policy
