"""Action layouts: the one definition of where each slot of an action lives.

Used by the scene (unpack), the HAL and the policies (pack), so no slot
arithmetic is ever copied. Layout, by control mode:

- JOINT_POSITION: ``[q_arm (n_arm)] + [grip]? + [vx, vy, wz]?``
- CARTESIAN_DELTA: ``[dx, dy, dz, dax, day, daz] + [grip]? + [vx, vy, wz]?``

``grip`` exists when the robot has a gripper (-1 open, +1 closed); the base
twist exists when it has a kinematic base (m/s, rad/s, base frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simseam.robot.spec import RobotSpec
from simseam.seam import ConfigError, ControlMode, SceneInfo

CARTESIAN_NAMES = ("dx", "dy", "dz", "dax", "day", "daz")
BASE_NAMES = ("vx", "vy", "wz")


@dataclass(frozen=True)
class ActionLayout:
    control_mode: ControlMode
    arm_names: tuple[str, ...]
    has_gripper: bool
    has_base: bool

    @classmethod
    def for_robot(cls, spec: RobotSpec, mode: ControlMode | str) -> "ActionLayout":
        mode = ControlMode.parse(mode)
        if mode == ControlMode.JOINT_POSITION:
            arm = tuple(j.name for j in spec.arm_joints)
        elif mode == ControlMode.CARTESIAN_DELTA:
            arm = CARTESIAN_NAMES
        else:
            raise ConfigError(
                f"robot {spec.name!r}: control mode {mode.value!r} cannot drive an arm; "
                "use joint_position or cartesian_delta"
            )
        return cls(mode, arm, spec.gripper is not None, spec.kinematic_base is not None)

    @classmethod
    def from_scene(cls, info: SceneInfo) -> "ActionLayout":
        """Rebuild the layout a rollout advertises (``SceneInfo.action_names``)."""
        names = tuple(info.action_names)
        has_base = names[-3:] == BASE_NAMES
        core = names[:-3] if has_base else names
        has_gripper = bool(core) and core[-1] == "grip"
        arm = core[:-1] if has_gripper else core
        layout = cls(ControlMode.parse(info.control_mode), arm, has_gripper, has_base)
        if layout.dim != info.action_dim:
            raise ConfigError(f"scene advertises action_dim {info.action_dim} but action names {names}")
        return layout

    @property
    def arm_dim(self) -> int:
        return len(self.arm_names)

    @property
    def dim(self) -> int:
        return self.arm_dim + int(self.has_gripper) + (3 if self.has_base else 0)

    @property
    def arm(self) -> slice:
        return slice(0, self.arm_dim)

    @property
    def grip(self) -> int | None:
        return self.arm_dim if self.has_gripper else None

    @property
    def base(self) -> slice | None:
        if not self.has_base:
            return None
        start = self.arm_dim + int(self.has_gripper)
        return slice(start, start + 3)

    @property
    def names(self) -> tuple[str, ...]:
        return self.arm_names + (("grip",) if self.has_gripper else ()) + (BASE_NAMES if self.has_base else ())

    def pack(self, arm=None, grip: float | None = None, base=None) -> np.ndarray:
        """Build an action; omitted parts are zero (grip 0 = half closed)."""
        out = np.zeros(self.dim, dtype=np.float32)
        if arm is not None:
            out[self.arm] = arm
        if grip is not None:
            if self.grip is None:
                raise ConfigError("this robot has no gripper")
            out[self.grip] = grip
        if base is not None:
            if self.base is None:
                raise ConfigError("this robot has no kinematic base")
            out[self.base] = base
        return out

    def unpack(self, action: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray | None]:
        """(arm part, grip scalar or None, base twist or None)."""
        grip = float(action[self.grip]) if self.grip is not None else None
        base = action[self.base] if self.base is not None else None
        return action[self.arm], grip, base
