"""robosuite's OSC_POSE controller and the Panda gripper's ramp as LIBERO configures them, batched over worlds.

One Warp kernel (``osc_kernel``: Warp's CPU device for NumPy arrays, CUDA for CuPy ones), float64, one thread per
world. Per physics substep (25 per 20 Hz control step), as robosuite's ``SingleArm.control`` does it:

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


def substep(xp, cfg: OscConfig, state: OscState, terms: Any, action, policy_step: bool) -> tuple[Any, Any, OscState]:
    """One physics substep of control for actions float[N, 7]: ``(arm torques [N, 7], finger ctrl [N, 2], state
    after)``, ``xp`` arrays. One Warp kernel over the worlds (``osc_kernel``: NumPy on Warp's CPU device, CuPy on
    its CUDA device): the goal where ``policy_step``, the torques, the gripper ramp; a world still holding
    robosuite's stale reading (``state.cached``) reads it, its bias forces live."""
    from simseam.backends.libero_gpu.osc_kernel import run_substep

    return run_substep(xp, cfg, state, terms, action, policy_step)
