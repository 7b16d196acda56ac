"""A LIBERO control step on MuJoCo Warp with robosuite's controller in the loop, for N worlds of one task.

robosuite, per substep: ``sim.forward()``, the controller reads the state and sets ``ctrl``, ``sim.step()``.
With LIBERO's Euler integrator that is MuJoCo Warp's ``step1`` (position and velocity stages: the terms the
controller reads), the batched controller (``control.substep``), the torques and finger ctrl written into the
worlds' ``ctrl``, then ``step2`` (actuation, acceleration, constraint solve, integration).
"""

from __future__ import annotations

from dataclasses import fields as dataclass_fields
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from simseam.backends.libero_gpu import control as C
from simseam.backends.libero_gpu.physics import ArmTerms, WarpTerms
from simseam.seam.errors import SimulationError

EULER = 0  # mjINT_EULER


def control_step(physics: WarpTerms, cfg: C.OscConfig, state: C.OscState, action: Any, facts: dict[str, Any],
                 after_substep: Callable[[], None] | None = None) -> C.OscState:
    """One 20 Hz control step (``cfg.substeps`` physics steps) of every world under ``action`` float[N, 7]
    (``xp`` of ``physics``); returns the controller's state after it. ``after_substep()`` runs after each
    physics step (where robosuite updates its observables)."""
    if int(physics.mjm.opt.integrator) != EULER:
        raise SimulationError("LIBERO port: the controller runs between step1 and step2, which needs the Euler "
                              f"integrator; this model uses integrator {int(physics.mjm.opt.integrator)}")
    xp = physics.xp
    arm, fingers = xp.asarray(np.asarray(facts["arm_actuators"])), xp.asarray(np.asarray(facts["gripper_actuators"]))
    ctrl = physics.view(physics.d.ctrl)
    for k in range(cfg.substeps):
        physics.step1()
        terms, bad = finite_terms(xp, physics.read())
        tau, grip, state = C.substep(xp, cfg, state, terms, action, k == 0)
        tau = xp.where(bad[:, None], 0.0, tau)
        ctrl[:, arm] = tau.astype(ctrl.dtype)
        ctrl[:, fingers] = grip.astype(ctrl.dtype)
        physics.step2()
        if after_substep is not None:
            after_substep()
    return state


def finite_terms(xp, terms: ArmTerms) -> tuple[ArmTerms, Any]:
    """``terms`` with the worlds whose reading is not finite (``bad``, bool[N]) read as a neutral state (zero
    Jacobian, identity inertia, zeros elsewhere), so that the batched linear algebra of the others runs; their
    torques are zeroed by the caller, and the batch ends their episodes."""
    fields = {f.name: getattr(terms, f.name) for f in dataclass_fields(terms)}
    bad = xp.zeros(len(terms.qpos), dtype=bool)
    for value in fields.values():
        bad |= ~xp.isfinite(value.reshape(len(value), -1)).all(axis=1)
    neutral = {"mass": xp.eye(terms.mass.shape[-1])[None], "ee_mat": xp.eye(3)[None]}
    out = {k: xp.where(bad.reshape((-1,) + (1,) * (v.ndim - 1)), neutral.get(k, 0.0), v) for k, v in fields.items()}
    return replace(terms, **out), bad
