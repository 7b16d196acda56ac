"""``BenchmarkRollout``: the seam's contract, once, for every benchmark backend.

A backend subclass builds its ``RolloutSpec`` and implements four primitives on the
benchmark's native environment: ``_native_reset(seed)``, ``_native_step(action) ->
(reward, success, diagnostics)``, ``_observe_native(request) -> dict`` (state, joints,
and images for the requested cameras) and ``_native_close()``. This class does the rest
the same way for all of them: action checks (``InvalidActionError``, nothing applied),
clipping to ``spec.action.clip``, the step count, ``info`` (success key, steps,
diagnostics), success terminating and ``spec.task.max_steps`` truncating, ``sim_time_ns``,
``render()`` and an idempotent ``close()``.

Imports numpy and simseam.seam only (it runs inside a backend's own interpreter).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.seam import (
    INFO_DIAGNOSTICS,
    INFO_STEPS,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    FieldSpec,
    ObservationSpec,
    ObsRequest,
    RolloutSpec,
    SimulationError,
    StepResult,
    check_action,
)
from simseam.seam.errors import ConfigError


def observation_spec(cameras: dict[str, tuple[int, int]], state_names: tuple[str, ...],
                     joint_names: tuple[str, ...], extra: dict[str, FieldSpec] | None = None) -> ObservationSpec:
    """The seam's required keys for a backend (+ ``extra`` declared keys)."""
    n = len(joint_names)
    fields = {
        OBS_IMAGES: FieldSpec("dict", entries={k: FieldSpec("uint8", (h, w, 3)) for k, (h, w) in cameras.items()}),
        OBS_STATE: FieldSpec("float32", (len(state_names),), names=state_names),
        OBS_TASK: FieldSpec("str"),
        OBS_JOINT_POSITIONS: FieldSpec("float32", (n,), names=joint_names),
        OBS_JOINT_VELOCITIES: FieldSpec("float32", (n,), names=joint_names),
        OBS_SIM_TIME_NS: FieldSpec("int", unit="ns"),
    }
    fields.update(extra or {})
    return ObservationSpec(fields)


def mount_rpy(cam_xmat: np.ndarray) -> tuple[float, float, float]:
    """roll, pitch, yaw of a MuJoCo camera's mount frame (+x along the view, +z up in the image).

    A MuJoCo camera looks along its -z with +y up in the image: the mount frame's axes are
    (-z_cam, -x_cam, +y_cam)."""
    r = np.asarray(cam_xmat, dtype=np.float64).reshape(3, 3)
    m = np.stack([-r[:, 2], -r[:, 0], r[:, 1]], axis=1)
    pitch = float(np.arcsin(-np.clip(m[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(m[2, 1], m[2, 2]))
    yaw = float(np.arctan2(m[1, 0], m[0, 0]))
    return roll, pitch, yaw


def check_keys(config: dict[str, Any], allowed: set[str], where: str) -> None:
    extra = sorted(set(config) - allowed)
    if extra:
        raise ConfigError(f"{where}: unknown field(s) {extra}; known: {sorted(allowed)}")


def check_image_size(value: Any, where: str) -> list[int]:
    if not (isinstance(value, (list, tuple)) and len(value) == 2 and all(
            isinstance(x, int) and not isinstance(x, bool) and 8 <= x <= 4096 for x in value)):
        raise ConfigError(f"{where}.image_size: expected [height, width] (8..4096), got {value!r}")
    return [int(value[0]), int(value[1])]


def check_int(value: Any, where: str, low: int = 1) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise ConfigError(f"{where}: expected an integer >= {low}, got {value!r}")
    return value


class BenchmarkRollout:
    """Base of every benchmark backend's ``SimRollout`` (see the module docstring)."""

    def __init__(self, spec: RolloutSpec):
        self._spec = spec
        self._closed = False
        self._steps = 0
        self._ready = False
        self._seeds = np.random.default_rng()

    # ------------------------------------------------------------ primitives
    def _native_reset(self, seed: int) -> None:
        raise NotImplementedError

    def _native_step(self, action: np.ndarray) -> tuple[float, bool, dict[str, Any]]:
        raise NotImplementedError

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        """state, joint_positions, joint_velocities, images (the requested cameras) and any extra keys."""
        raise NotImplementedError

    def _render_camera(self, key: str) -> np.ndarray:
        raise NotImplementedError

    def _sim_time_s(self) -> float:
        raise NotImplementedError

    def _native_close(self) -> None:
        pass

    # ------------------------------------------------------------------ seam
    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def action_dim(self) -> int:
        return self._spec.action.dim

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError(f"the {self._spec.engine} rollout is closed")

    def _observe(self, request: ObsRequest | None) -> dict[str, Any]:
        obs = self._observe_native(request or ObsRequest())
        obs[OBS_TASK] = self._spec.task.instruction
        obs[OBS_SIM_TIME_NS] = self.sim_time_ns()
        return obs

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> dict[str, Any]:
        self._check_open()
        if seed is None:
            seed = int(self._seeds.integers(0, 2**31 - 1))
        self._native_reset(int(seed))
        self._t0 = self._sim_time_s()
        self._steps = 0
        self._ready = True
        return self._observe(observe)

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult:
        self._check_open()
        a = check_action(action, self.action_dim)
        if not self._ready:
            raise SimulationError("step() before reset()")
        a = self._spec.action.clip(a).astype(np.float32)
        reward, success, diagnostics = self._native_step(a)
        self._steps += 1
        success = bool(success)
        info = {self._spec.task.success_key: success, INFO_STEPS: self._steps, INFO_DIAGNOSTICS: diagnostics}
        truncated = not success and self._steps >= self._spec.task.max_steps
        return StepResult(self._observe(observe), float(reward), success, truncated, info)

    def render(self) -> np.ndarray | None:
        self._check_open()
        cams = list(self._spec.observation.images)
        return self._render_camera(cams[0]) if cams and self._ready else None

    def sim_time_ns(self) -> int:
        if not self._ready:
            return 0
        return int(round((self._sim_time_s() - self._t0) * 1e9))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._native_close()
