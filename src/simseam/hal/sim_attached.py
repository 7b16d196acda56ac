"""SimAttachedHAL: any ``SimRollout`` driven like a real robot.

A real robot's driver does not take one action vector per control period from
one caller: it takes the latest command for each part (arm, gripper, base) from
whoever sends it, at whatever rate, runs its own control loop, keeps its
sensors publishing when nobody commands it, stops on its own when commands stop
arriving, and honours an E-stop. This class gives a simulated rollout (an
in-process ``ManifestScene`` or a ``SidecarRollout``) exactly that shape, so a
ROS 2 bridge or a teleop loop can sit on top of it.

Semantics (decided here, tested in ``tests/hal``):

- ``connect()`` resets the rollout and takes everything else from its
  ``RolloutSpec``: the action slots and their bounds (``spec.action``, the one
  definition the scene unpacks with), joint names, the gripper's open/closed
  positions and the base's joints (``spec.robot``), the control rate.
- ``send_action(values, mode)`` stores the latest command of one part, stamped
  with the current SIM time. Modes: JOINT_POSITION (absolute arm joint targets,
  manifest order, only on a joint_position rollout), CARTESIAN_DELTA (6 values,
  clipped to [-1, 1], only on a cartesian_delta rollout; applied on every tick
  while fresh, i.e. it behaves as an end-effector velocity command), GRIPPER
  (one scalar, -1 open .. +1 closed), BODY_TWIST (``[vx, vy, wz]``, base frame,
  only with a kinematic base). A mode the rollout cannot express is a
  ``ConfigError``; a wrong length or a non-finite value an
  ``InvalidActionError`` (nothing is stored).
- ``tick()`` steps the rollout once with the latest commands packed into
  the action slots. A motion command older than ``hold_time_s`` of sim time is no longer
  applied: the arm holds (zero Cartesian delta; in joint-position mode the arm
  joints measured when the hold began), the twist is zero. The gripper keeps
  its last value. Ticks without any command keep the sensors live.
- Commands are clipped to the action spec's slot bounds (``spec.action.clip_group``:
  joint limits, [-1, 1], the base's speed limits); ``joint_limits`` narrows the
  arm joints' further. With ``max_joint_speed``,
  the applied target moves toward the command by at most
  ``max_joint_speed / control_hz`` per tick (a rate limiter in sim time). The
  rollout applies the URDF velocity limits on top.
- ``estop()`` latches: the stored arm and twist commands are discarded at once
  (the next tick holds the arm and applies a zero twist) and every command
  sent while engaged (gripper included) is dropped and counted in
  ``dropped_commands``; ``estop(False)`` clears the latch, after which only new
  commands are obeyed (nothing from before the E-stop resumes).
- A sim scene never attaches to a real-hardware HAL: ``attach(target='real')``
  is a ``ConfigError``.

Thread safety: ``send_action``, ``estop`` and ``tick`` take one lock, so a
bridge may call ``send_action`` from subscriber threads while a timer ticks.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from simseam.seam import (
    ActionSpec,
    ConfigError,
    ControlMode,
    InvalidActionError,
    ObsRequest,
    Observation,
    SimRollout,
    SimulationError,
    StepResult,
)

SIM_TARGETS = ("sim", "simulation", "simulator")
REAL_TARGETS = ("real", "hardware", "hw", "robot", "physical")


class NotConnectedError(SimulationError):
    """The HAL was used before ``connect()`` (or after ``close()``)."""


@dataclass(frozen=True)
class JointState:
    """Joint names, positions and velocities (float64) in manifest order, stamped in sim time."""

    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    stamp_ns: int


class SimAttachedHAL:
    """A robot interface over any ``SimRollout`` (see the module docstring)."""

    def __init__(self, rollout: SimRollout, *, hold_time_s: float = 0.5, seed: int | None = 0,
                 joint_limits: dict[str, tuple[float, float]] | None = None,
                 max_joint_speed: float | None = None):
        if not (hold_time_s > 0 and math.isfinite(hold_time_s)):
            raise ConfigError(f"hold_time_s must be positive and finite, got {hold_time_s!r}")
        if max_joint_speed is not None and not (max_joint_speed > 0):
            raise ConfigError(f"max_joint_speed must be positive, got {max_joint_speed!r}")
        self.rollout = rollout
        self.hold_time_s = float(hold_time_s)
        self._hold_ns = int(round(hold_time_s * 1e9))
        self.seed = seed
        self._user_limits = dict(joint_limits or {})
        self.max_joint_speed = None if max_joint_speed is None else float(max_joint_speed)
        self._lock = threading.Lock()
        self._connected = False
        self._action: ActionSpec | None = None
        self._obs: Observation = {}
        self._estopped = False
        self._dropped = 0

    # ------------------------------------------------------------ construction
    @classmethod
    def attach(cls, rollout: SimRollout, *, target: str = "sim", **kw: Any) -> "SimAttachedHAL":
        """A HAL for ``rollout``. Only ``target='sim'``: a sim scene cannot drive real hardware."""
        t = str(target).strip().lower()
        if t in REAL_TARGETS:
            raise ConfigError(f"a sim scene cannot attach to a real-hardware HAL (target={target!r}); "
                              "use target='sim'")
        if t not in SIM_TARGETS:
            raise ConfigError(f"unknown HAL target {target!r}; a sim rollout attaches to target='sim'")
        return cls(rollout, **kw)

    def connect(self) -> None:
        """Reset the rollout and take the action slots, joints and limits from its spec."""
        with self._lock:
            spec = self.rollout.spec
            slots = spec.action
            if slots.dim != self.rollout.action_dim:
                raise ConfigError(f"rollout action_dim {self.rollout.action_dim} but its spec's action "
                                  f"{slots.names} has {slots.dim} slots")
            self.spec = spec
            self._action = slots
            self._names = tuple(spec.robot.joint_names)
            self._index = {n: i for i, n in enumerate(self._names)}
            self._dt_ns = int(round(1e9 / spec.control_hz))
            self._setup_limits(slots)
            robot = spec.robot
            self._base_idx = None
            if robot.base is not None and slots.has_base and all(n in self._index for n in robot.base.joints):
                self._base_idx = np.array([self._index[n] for n in robot.base.joints])
            self._grip_fingers = None
            if robot.gripper is not None and slots.has_gripper and all(n in self._index for n in robot.gripper.joints):
                self._grip_fingers = np.array([self._index[n] for n in robot.gripper.joints])
            self._request = ObsRequest()

            obs = self.rollout.reset(self.seed)
            self._obs = obs
            self._prev_pose = self._pose_of(obs)
            self._prev_pose_ns = int(obs["sim_time_ns"])
            # command state: (values, stamp_ns) of the latest arm / twist command
            self._arm_cmd: tuple[np.ndarray, int] | None = None
            self._twist_cmd: tuple[np.ndarray, int] | None = None
            self._grip = self._measured_grip(obs)
            self._arm_hold: np.ndarray | None = self._measured_arm(obs)
            self._q_applied = self._arm_hold  # last arm target sent (joint-position mode)
            self._estopped = False
            self._dropped = 0
            self._last_action = None
            self._connected = True

    def _setup_limits(self, slots: ActionSpec) -> None:
        self._arm_idx = None
        self._lo = self._hi = None
        if slots.control_mode != ControlMode.JOINT_POSITION:
            return
        missing = [n for n in slots.arm_names if n not in self._index]
        if missing:
            raise ConfigError(f"the rollout's arm joints {missing} are not among its joint names {self._names}")
        self._arm_idx = np.array([self._index[n] for n in slots.arm_names])
        unknown = sorted(set(self._user_limits) - set(slots.arm_names))
        if unknown:
            raise ConfigError(f"joint_limits names joints that are not arm joints of this rollout: {unknown}; "
                              f"arm joints: {list(slots.arm_names)}")
        lo, hi = slots.low[slots.arm], slots.high[slots.arm]
        for k, name in enumerate(slots.arm_names):
            if name in self._user_limits:
                lower, upper = (float(x) for x in self._user_limits[name])
                if lower > upper:
                    raise ConfigError(f"joint_limits[{name!r}]: lower {lower} > upper {upper}")
                lo[k], hi[k] = max(lo[k], lower), min(hi[k], upper)
        self._lo, self._hi = lo, hi

    # -------------------------------------------------------------- properties
    def _require(self) -> ActionSpec:
        if not self._connected or self._action is None:
            raise NotConnectedError("the HAL is not connected: call connect() first")
        return self._action

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def action(self) -> ActionSpec:
        """The rollout's action slots (``spec.action``)."""
        return self._require()

    @property
    def action_dim(self) -> int:
        return self._require().dim

    @property
    def joint_names(self) -> tuple[str, ...]:
        self._require()
        return self._names

    @property
    def control_hz(self) -> float:
        return float(self.rollout.spec.control_hz)

    @property
    def control_mode(self) -> ControlMode:
        """The rollout's arm control mode (JOINT_POSITION or CARTESIAN_DELTA)."""
        return self._require().control_mode

    @property
    def estopped(self) -> bool:
        return self._estopped

    @property
    def dropped_commands(self) -> int:
        return self._dropped

    @property
    def last_action(self) -> np.ndarray | None:
        """The packed action of the last tick (a copy), or None before the first tick."""
        return None if self._last_action is None else self._last_action.copy()

    def supported_modes(self) -> tuple[ControlMode, ...]:
        """The command modes this rollout can express."""
        slots = self._require()
        modes = [slots.control_mode]
        if slots.has_gripper:
            modes.append(ControlMode.GRIPPER)
        if slots.has_base:
            modes.append(ControlMode.BODY_TWIST)
        return tuple(modes)

    # ----------------------------------------------------------------- sensors
    def read_state(self) -> JointState:
        self._require()
        obs = self._obs
        pos = np.array(obs["joint_positions"], dtype=np.float64)
        vel = np.array(obs["joint_velocities"], dtype=np.float64)
        pose = obs.get("base_pose")
        if pose is not None and self._base_idx is not None:
            pos[self._base_idx] = np.asarray(pose, dtype=np.float64)  # base joints are the base pose
        return JointState(self._names, pos, vel, int(obs["sim_time_ns"]))

    def read_images(self) -> dict[str, np.ndarray]:
        self._require()
        return dict(self._obs.get("images") or {})

    def read_depth_clouds(self) -> dict[str, np.ndarray]:
        self._require()
        return dict(self._obs.get("depth_points") or {})

    def read_scan(self) -> np.ndarray | None:
        self._require()
        return self._obs.get("scan")

    def base_pose(self) -> np.ndarray | None:
        """``[x, y, yaw]`` of the base link in the world, or None without a kinematic base."""
        self._require()
        pose = self._obs.get("base_pose")
        return None if pose is None else np.asarray(pose, dtype=np.float64).copy()

    def base_twist(self) -> np.ndarray | None:
        """``[vx, vy, wz]`` in the base frame (odometry twist), or None without a kinematic base.

        From the base joint velocities (world-frame ``[xdot, ydot, yawdot]``)
        rotated into the base frame; when the spec names no base joints, from
        the pose change over the last tick.
        """
        self._require()
        obs = self._obs
        pose = obs.get("base_pose")
        if pose is None:
            return None
        yaw = float(pose[2])
        if self._base_idx is not None:
            xd, yd, wz = (float(v) for v in np.asarray(obs["joint_velocities"])[self._base_idx])
        else:
            dt = (int(obs["sim_time_ns"]) - self._prev_pose_ns) * 1e-9
            if dt <= 0 or self._prev_pose is None:
                return np.zeros(3)
            d = np.asarray(pose, dtype=np.float64) - self._prev_pose
            d[2] = math.atan2(math.sin(d[2]), math.cos(d[2]))
            xd, yd, wz = d / dt
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([c * xd + s * yd, -s * xd + c * yd, wz])

    def sim_time_ns(self) -> int:
        return int(self.rollout.sim_time_ns())

    def last_observation(self) -> dict:
        self._require()
        return self._obs

    # ---------------------------------------------------------------- commands
    def send_action(self, values: Any, mode: ControlMode | str) -> None:
        """Store the latest command for one part (see the module docstring)."""
        mode = ControlMode.parse(mode)
        with self._lock:
            slots = self._require()
            if mode in (ControlMode.JOINT_POSITION, ControlMode.CARTESIAN_DELTA):
                if mode != slots.control_mode:
                    raise ConfigError(f"this rollout is in {slots.control_mode.value!r} control mode and cannot "
                                      f"express {mode.value!r} commands (build the scene with "
                                      f"control_mode={mode.value!r})")
                n = slots.arm_dim
            elif mode == ControlMode.GRIPPER:
                if not slots.has_gripper:
                    raise ConfigError("this rollout's robot has no gripper: it cannot express 'gripper' commands")
                n = 1
            else:  # BODY_TWIST
                if not slots.has_base:
                    raise ConfigError("this rollout's robot has no kinematic base (a fixed arm): "
                                      "it cannot express 'body_twist' commands")
                n = 3
            v = self._check(values, mode, n)
            if self._estopped:
                self._dropped += 1
                return
            now = int(self._obs["sim_time_ns"])
            if mode == ControlMode.JOINT_POSITION:
                self._arm_cmd = (np.clip(v, self._lo, self._hi), now)
            elif mode == ControlMode.CARTESIAN_DELTA:
                self._arm_cmd = (slots.clip_group("arm", v), now)
            elif mode == ControlMode.GRIPPER:
                self._grip = float(slots.clip_group("grip", v)[0])
            else:
                self._twist_cmd = (slots.clip_group("base", v), now)

    @staticmethod
    def _check(values: Any, mode: ControlMode, n: int) -> np.ndarray:
        try:
            v = np.atleast_1d(np.asarray(values, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise InvalidActionError(f"{mode.value} command is not numeric: {exc}") from None
        if v.ndim != 1 or v.shape[0] != n:
            raise InvalidActionError(f"{mode.value} command has shape {tuple(v.shape)}, expected {n} "
                                     f"value{'s' if n != 1 else ''}")
        finite = np.isfinite(v)
        if not finite.all():
            bad = int(np.flatnonzero(~finite)[0])
            raise InvalidActionError(f"{mode.value} command[{bad}] is {v[bad]}; expected {n} finite values")
        return v.copy()

    def estop(self, engaged: bool = True) -> None:
        """Engage (latch) or clear the E-stop."""
        with self._lock:
            self._require()
            if engaged and not self._estopped:
                self._arm_cmd = None
                self._twist_cmd = None
                self._arm_hold = self._measured_arm(self._obs)
                if self._arm_hold is not None:
                    self._q_applied = self._arm_hold
            self._estopped = bool(engaged)

    # -------------------------------------------------------------------- loop
    def observe(self, request: ObsRequest) -> None:
        """What the following ticks observe (e.g. images only on the ticks a camera topic publishes)."""
        with self._lock:
            self._request = request

    def tick(self) -> StepResult:
        """One rollout step with the latest fresh commands (holds otherwise)."""
        with self._lock:
            slots = self._require()
            now = int(self._obs["sim_time_ns"])
            arm_cmd, twist_cmd = self._arm_cmd, self._twist_cmd
            arm_fresh = arm_cmd is not None and now - arm_cmd[1] < self._hold_ns
            twist_fresh = twist_cmd is not None and now - twist_cmd[1] < self._hold_ns
            if slots.control_mode == ControlMode.JOINT_POSITION:
                if arm_fresh:
                    self._arm_hold = None
                    target = arm_cmd[0]
                    if self.max_joint_speed is not None:
                        step = self.max_joint_speed * self._dt_ns * 1e-9
                        prev = self._q_applied
                        target = np.clip(target, prev - step, prev + step)
                else:
                    if self._arm_hold is None:  # the hold begins: keep the arm where it is now
                        self._arm_hold = self._measured_arm(self._obs)
                    target = self._arm_hold
                self._q_applied = target
                arm = target
            else:
                arm = arm_cmd[0] if arm_fresh else None  # None packs a zero delta: hold the pose
            grip = self._grip if slots.has_gripper else None
            base = (twist_cmd[0] if twist_fresh else np.zeros(3)) if slots.has_base else None
            action = slots.pack(arm=arm, grip=grip, base=base)
            result = self.rollout.step(action, self._request)
            self._last_action = action
            self._prev_pose = self._pose_of(self._obs)
            self._prev_pose_ns = now
            self._obs = result.observation
            return result

    def close(self) -> None:
        """Close the rollout; the HAL is disconnected."""
        with self._lock:
            self._connected = False
            self.rollout.close()

    def __enter__(self) -> "SimAttachedHAL":
        if not self._connected:
            self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ----------------------------------------------------------------- helpers
    @staticmethod
    def _pose_of(obs: Observation) -> np.ndarray | None:
        pose = obs.get("base_pose")
        return None if pose is None else np.asarray(pose, dtype=np.float64).copy()

    def _measured_arm(self, obs: Observation) -> np.ndarray | None:
        if self._arm_idx is None:
            return None
        return np.asarray(obs["joint_positions"], dtype=np.float64)[self._arm_idx].copy()

    def _measured_grip(self, obs: Observation) -> float:
        """The gripper command matching the fingers' measured opening (-1 open when unknown)."""
        if self._grip_fingers is None:
            return -1.0
        q = np.asarray(obs["joint_positions"], dtype=np.float64)[self._grip_fingers]
        return self.spec.robot.gripper.command_of(q)
