"""robosuite's OSC_POSE controller and the Panda gripper's ramp as LIBERO configures them, batched over worlds.

Array code over ``xp`` (NumPy on the CPU, CuPy on a CUDA device: the same functions), float64, one row per world.
Per physics substep (25 per 20 Hz control step), as robosuite's ``SingleArm.control`` does it:

- on the control step's first substep only (``policy_step``), the goal: the arm action clipped to the input
  range and scaled (0.05 m, 0.5 rad per unit), ``goal_pos = ee_pos + delta``; the goal orientation turns by the
  axis-angle delta from the current orientation, but only where that delta is not exactly zero (otherwise it
  keeps the previous goal: state);
- every substep, the torques from that substep's state (``physics.ArmTerms``): the pose and velocity errors
  times kp / kd (kp 150, damping ratio 1), decoupled through the position and orientation operational-space
  inertias ``pinv(J M^-1 J^T)``, mapped by ``J^T``, plus the bias forces (gravity, Coriolis) and the nullspace
  term ``N^T M (kp_n (q0 - q) - kv_n qd)`` (kp_n 10, kv_n 2 sqrt(kp_n); ``q0`` the controller's initial joints,
  ``N = I - Jbar J``), then clipped to the actuators' torque limits;
- every substep, the gripper: its ramp state moves by ``[-1, +1] * 0.01 * sign(grip)``, clipped to [-1, 1]
  (state), and becomes ``ctrl = mid + half_range * state`` of the two finger actuators.

What robosuite's controller supports beyond LIBERO's configuration (variable impedance, interpolators, position
and orientation limits, absolute mode) is refused by ``OscConfig.from_facts`` with a one-line error.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from simseam.seam.errors import SimulationError

PINV_RCOND = 1e-15  # numpy.linalg.pinv's default cutoff, relative to the largest singular value


@dataclass(frozen=True)
class OscConfig:
    """The controller's constants, read from robosuite's own objects by the native worker
    (``native.controller_facts``) and the model's gripper actuator ranges."""

    kp: np.ndarray  # [6]
    kd: np.ndarray  # [6]
    input_min: np.ndarray  # [6]
    input_max: np.ndarray  # [6]
    scale: np.ndarray  # [6]: output range / input range
    input_mid: np.ndarray  # [6]
    output_mid: np.ndarray  # [6]
    torque_low: np.ndarray  # [7]
    torque_high: np.ndarray  # [7]
    nullspace_kp: float
    grip_speed: float
    grip_mid: np.ndarray  # [2]: the finger actuators' ctrlrange centres
    grip_half: np.ndarray  # [2]: ... and half widths
    substeps: int

    @classmethod
    def from_facts(cls, facts: dict[str, Any], mjm: Any) -> "OscConfig":
        unsupported = {"controller": facts["name"] != "OSC_POSE", "impedance_mode": facts["impedance_mode"] != "fixed",
                       "interpolator": facts["interpolator"], "position_limits": facts["position_limits"] is not None,
                       "orientation_limits": facts["orientation_limits"] is not None,
                       "absolute (not delta) control": not facts["use_delta"], "uncoupled": not facts["uncoupling"],
                       "gripper": facts["gripper"] != "PandaGripper"}
        bad = [k for k, v in unsupported.items() if v]
        if bad:
            raise SimulationError(f"LIBERO port: robosuite controller settings not batched here: {', '.join(bad)} "
                                  f"(controller {facts['name']}, gripper {facts['gripper']})")
        f = {k: np.asarray(facts[k], dtype=np.float64) for k in ("kp", "kd", "input_min", "input_max", "output_min",
                                                                  "output_max", "torque_low", "torque_high")}
        ctrlrange = np.asarray(mjm.actuator_ctrlrange, dtype=np.float64)[np.asarray(facts["gripper_actuators"])]
        return cls(kp=f["kp"], kd=f["kd"], input_min=f["input_min"], input_max=f["input_max"],
                   scale=np.abs(f["output_max"] - f["output_min"]) / np.abs(f["input_max"] - f["input_min"]),
                   input_mid=(f["input_max"] + f["input_min"]) / 2.0, output_mid=(f["output_max"] + f["output_min"]) / 2.0,
                   torque_low=f["torque_low"], torque_high=f["torque_high"], nullspace_kp=float(facts["nullspace_kp"]),
                   grip_speed=float(facts["gripper_speed"]), grip_mid=ctrlrange.mean(axis=1),
                   grip_half=0.5 * (ctrlrange[:, 1] - ctrlrange[:, 0]), substeps=int(facts["substeps"]))


CACHED = ("ee_pos", "ee_mat", "jac", "mass", "qpos", "qvel")  # what a skipped update leaves stale (not the bias)


@dataclass
class OscState:
    """What carries over between substeps, per world: the goal pose, the nullspace target, the gripper's
    ramp state (arrays of ``xp``, float64) and, right after a reset, the controller's cached reading.

    robosuite's controller refreshes its reading of the state only when its last substep ended (``new_update``);
    after a reset it still holds what it read when it was made (the robot's reset pose, before LIBERO's
    ``set_init_state`` moved everything), so the episode's first substep sets its goal from, and computes its
    torques with, that stale pose, Jacobian, inertia and joint state (the bias forces are read live).
    ``cached`` (``ArmTerms``-like, ``bias`` unused) and ``cached_mask`` [N] hold that reading for the worlds
    whose next substep uses it; None once used."""

    goal_pos: Any  # [N, 3]
    goal_ori: Any  # [N, 3, 3]
    initial_joint: Any  # [N, 7]
    grip: Any  # [N, 2]
    cached: Any = None
    cached_mask: Any = None

    @classmethod
    def from_native(cls, xp, starts: list[dict[str, Any]]) -> "OscState":
        """From the native controller's state after each world's reset (``native.record``'s ``start``)."""
        def stack(key):
            return xp.asarray(np.stack([np.asarray(s[key], np.float64) for s in starts]))

        state = cls(stack("goal_pos"), stack("goal_ori"), stack("initial_joint"), stack("grip"))
        if all(s["cached"] is None for s in starts):
            return state
        from simseam.backends.libero_gpu.physics import ArmTerms

        shapes = {"ee_pos": (3,), "ee_mat": (3, 3), "jac": (6, 7), "mass": (7, 7), "qpos": (7,), "qvel": (7,)}
        fields = {k: xp.asarray(np.stack([np.zeros(shapes[k]) if s["cached"] is None else np.asarray(s["cached"][k])
                                          for s in starts])) for k in CACHED}
        mask = xp.asarray(np.array([s["cached"] is not None for s in starts]))
        return replace(state, cached=ArmTerms(bias=None, **fields), cached_mask=mask)


def reading(xp, state: OscState, terms: Any) -> Any:
    """What the controller reads this substep: ``terms``, or the cached reading where a world still holds one
    (its bias forces live)."""
    if state.cached is None:
        return terms
    picked = {}
    for key in CACHED:
        fresh = getattr(terms, key)
        mask = state.cached_mask.reshape((-1,) + (1,) * (fresh.ndim - 1))
        picked[key] = xp.where(mask, getattr(state.cached, key), fresh)
    return replace(terms, **picked)


def axis_angle_matrix(xp, rotvec):
    """float[N, 3] axis-angle -> float[N, 3, 3] as robosuite turns it (``axisangle2quat`` then its numba-compiled
    ``quat2mat``, which rounds the quaternion to float32: its products and off-diagonal sums are float32, its
    diagonal ``1 - a - b`` float64); a zero vector is the identity. Measured against robosuite's own on 2,000
    random rotations: equal in 84 %, one float32 ulp (1.2e-7) apart in the rest (its float32 normalisation's
    rounding is not reproduced bit for bit)."""
    angle = xp.sqrt(xp.sum(rotvec * rotvec, axis=-1))
    safe = xp.where(angle > 0, angle, 1.0)
    axis = rotvec / safe[:, None]
    half = 0.5 * angle
    quat = xp.concatenate([xp.cos(half)[:, None], axis * xp.sin(half)[:, None]], axis=-1)
    quat = xp.where((angle > 0)[:, None], quat, xp.asarray([1.0, 0.0, 0.0, 0.0]))
    q = quat.astype(xp.float32)
    norm = xp.sum(q.astype(xp.float64) ** 2, axis=-1).astype(xp.float32)
    q = (q.astype(xp.float64) * xp.sqrt(2.0 / norm.astype(xp.float64))[:, None]).astype(xp.float32)
    q2 = q[:, :, None] * q[:, None, :]  # float32 outer product, w x y z
    d = q2.astype(xp.float64)
    w, x, y, z = 0, 1, 2, 3
    rows = [1.0 - d[:, y, y] - d[:, z, z], q2[:, x, y] - q2[:, z, w], q2[:, x, z] + q2[:, y, w],
            q2[:, x, y] + q2[:, z, w], 1.0 - d[:, x, x] - d[:, z, z], q2[:, y, z] - q2[:, x, w],
            q2[:, x, z] - q2[:, y, w], q2[:, y, z] + q2[:, x, w], 1.0 - d[:, x, x] - d[:, y, y]]
    return xp.stack([r.astype(xp.float64) for r in rows], axis=-1).reshape(-1, 3, 3)


def set_goal(xp, cfg: OscConfig, state: OscState, terms: Any, action) -> OscState:
    """A control step's goal from ``action`` float[N, >=6] (its first 6 slots) and the substep's pose."""
    arm = xp.clip(action[:, :6], xp.asarray(cfg.input_min), xp.asarray(cfg.input_max))
    delta = (arm - xp.asarray(cfg.input_mid)) * xp.asarray(cfg.scale) + xp.asarray(cfg.output_mid)
    turn = xp.any(delta[:, 3:] != 0.0, axis=-1)
    turned = xp.matmul(axis_angle_matrix(xp, delta[:, 3:]), terms.ee_mat)
    goal_ori = xp.where(turn[:, None, None], turned, state.goal_ori)
    return replace(state, goal_pos=terms.ee_pos + delta[:, :3], goal_ori=goal_ori)


def orientation_error(xp, desired, current):
    """robosuite's ``orientation_error``: half the sum of the columns' cross products (current x desired)."""
    return 0.5 * xp.sum(xp.cross(xp.swapaxes(current, -1, -2), xp.swapaxes(desired, -1, -2)), axis=-2)


def pinv(xp, a):
    """Batched Moore-Penrose inverse by SVD, numpy.linalg.pinv's cutoff."""
    u, s, vh = xp.linalg.svd(a)
    cutoff = PINV_RCOND * xp.max(s, axis=-1, keepdims=True)
    inv_s = xp.where(s > cutoff, 1.0 / xp.where(s > cutoff, s, 1.0), 0.0)
    return xp.matmul(xp.swapaxes(vh, -1, -2) * inv_s[..., None, :], xp.swapaxes(u, -1, -2))


def arm_torques(xp, cfg: OscConfig, state: OscState, terms: Any):
    """The clipped joint torques float[N, 7] for this substep's state (``terms``) and goal (``state``)."""
    jac, mass = terms.jac, terms.mass
    jt = xp.swapaxes(jac, -1, -2)
    vel = xp.einsum("nij,nj->ni", jac, terms.qvel)
    kp, kd = xp.asarray(cfg.kp), xp.asarray(cfg.kd)
    force = (state.goal_pos - terms.ee_pos) * kp[:3] - vel[:, :3] * kd[:3]
    torque = orientation_error(xp, state.goal_ori, terms.ee_mat) * kp[3:] - vel[:, 3:] * kd[3:]
    minv = xp.linalg.inv(mass)
    lam_full = pinv(xp, jac @ minv @ jt)
    lam_pos = pinv(xp, jac[:, :3] @ minv @ jt[:, :, :3])
    lam_ori = pinv(xp, jac[:, 3:] @ minv @ jt[:, :, 3:])
    wrench = xp.concatenate([xp.einsum("nij,nj->ni", lam_pos, force), xp.einsum("nij,nj->ni", lam_ori, torque)], axis=-1)
    tau = xp.einsum("nij,nj->ni", jt, wrench) + terms.bias
    jbar = minv @ jt @ lam_full
    null = xp.eye(jac.shape[-1])[None] - jbar @ jac
    kv = np.sqrt(cfg.nullspace_kp) * 2.0
    pose = xp.einsum("nij,nj->ni", mass, cfg.nullspace_kp * (state.initial_joint - terms.qpos) - kv * terms.qvel)
    tau = tau + xp.einsum("nji,nj->ni", null, pose)
    return xp.clip(tau, xp.asarray(cfg.torque_low), xp.asarray(cfg.torque_high))


def gripper_ctrl(xp, cfg: OscConfig, state: OscState, grip_action) -> tuple[Any, OscState]:
    """The finger actuators' ctrl float[N, 2] for grip actions float[N] and the ramp state after this substep."""
    step = xp.asarray([-1.0, 1.0]) * cfg.grip_speed * xp.sign(grip_action)[:, None]
    grip = xp.clip(state.grip + step, -1.0, 1.0)
    return xp.asarray(cfg.grip_mid) + xp.asarray(cfg.grip_half) * grip, replace(state, grip=grip)


def substep(xp, cfg: OscConfig, state: OscState, terms: Any, action, policy_step: bool) -> tuple[Any, Any, OscState]:
    """One physics substep of control for actions float[N, 7]: ``(arm torques [N, 7], finger ctrl [N, 2],
    state after)``."""
    read = reading(xp, state, terms)
    if policy_step:
        state = set_goal(xp, cfg, state, read, action)
    tau = arm_torques(xp, cfg, state, read)
    fingers, state = gripper_ctrl(xp, cfg, state, action[:, 6])
    return tau, fingers, replace(state, cached=None, cached_mask=None)
