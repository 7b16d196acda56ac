"""Synthetic ``RolloutSpec``s for tests that need a rollout description without a simulator."""

from __future__ import annotations

import dataclasses

from simseam.seam import (
    OBS_ENV_STATE,
    OBS_IMAGES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ControlMode,
    FieldSpec,
    JointFacts,
    ObservationSpec,
    RobotFacts,
    RolloutSpec,
    TaskSpec,
)


def misfit(spec: RolloutSpec, *, cameras: dict | None = None, state_dim: int | None = None,
           control_mode: ControlMode | None = None, action_dim: int | None = None,
           control_hz: float | None = None, env_state_dim: int | None = None) -> RolloutSpec:
    """``spec`` with the named parts changed (what a policy contract is checked against)."""
    fields = dict(spec.observation.fields)
    if env_state_dim is not None:
        fields[OBS_ENV_STATE] = FieldSpec("float32", (env_state_dim,))
    if cameras is not None:
        fields[OBS_IMAGES] = FieldSpec("dict", entries={k: FieldSpec("uint8", (h, w, 3)) for k, (h, w) in cameras.items()})
    if state_dim is not None:
        fields[OBS_STATE] = FieldSpec("float32", (state_dim,))
    action = spec.action
    if control_mode is not None or action_dim is not None:
        n = action.dim if action_dim is None else action_dim
        action = ActionSpec(control_mode or action.control_mode,
                            tuple(ActionSlot(f"a{i}", "arm", -1.0, 1.0) for i in range(n)))
    return dataclasses.replace(spec, observation=ObservationSpec(fields), action=action,
                               control_hz=spec.control_hz if control_hz is None else control_hz)


def make_spec(*, robot: str = "franka_panda", task: str = "lift_cube", control_mode=ControlMode.CARTESIAN_DELTA,
              action_dim: int = 7, state_dim: int = 8, control_hz: float = 20.0,
              cameras: dict | None = None, env_state_dim: int | None = None) -> RolloutSpec:
    """A minimal spec: one arm joint, ``action_dim`` slots in [-1, 1], the given cameras and state size."""
    base = RolloutSpec(
        robot=RobotFacts(robot, "base", "tool", (JointFacts("j1", "arm", -1.0, 1.0),)),
        task=TaskSpec(task, "do it"),
        observation=ObservationSpec({}), action=ActionSpec(control_mode, ()), engine="mujoco", control_hz=control_hz)
    return misfit(base, cameras=cameras if cameras is not None else {"camera1": (96, 96), "camera2": (96, 96)},
                  state_dim=state_dim, control_mode=control_mode, action_dim=action_dim, env_state_dim=env_state_dim)
