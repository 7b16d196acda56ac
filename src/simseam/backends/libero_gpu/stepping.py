"""A LIBERO control step on MuJoCo Warp with robosuite's controller in the loop, for N worlds of one task.

robosuite, per substep: ``sim.forward()``, the controller reads the state and sets ``ctrl``, ``sim.step()``.
With LIBERO's Euler integrator that is ``step1`` (position and velocity stages: the terms the controller reads),
the batched controller (``osc_kernel``: the same Warp kernel for both engines), the torques and finger ctrl
written into the worlds' ``ctrl``, then ``step2`` (actuation, acceleration, constraint solve, integration).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from simseam.backends.libero_gpu import control as C
from simseam.seam.errors import SimulationError

EULER = 0  # mjINT_EULER


def control_step(physics: Any, cfg: C.OscConfig, state: C.OscState, action: Any, facts: dict[str, Any],
                 after_substep: Callable[[], None] | None = None, sampler: Any = None, images: Any = None,
                 drawn: tuple[int, ...] = ()) -> C.OscState:
    """One 20 Hz control step (``cfg.substeps`` physics steps) of every world under ``action`` float[N, 7]
    (``xp`` of ``physics``); returns the controller's state after it. ``after_substep()`` runs after each
    physics step (where robosuite updates its observables). A world whose reading is not finite gets zero
    torques (the batch ends its episode). MuJoCo Warp's worlds run each substep as device launches only
    (``physics.ControllerReads.control_substep``), or with ``sampler`` (``observables.Sampler``, loaded: the
    observables sampled on the device, in place of ``after_substep``; with ``images``, an
    ``observables.ImageSampler``, the cameras drawn after the substeps ``drawn``) the whole step as device launches
    (``control_substeps``); CPU MuJoCo's world is read, controlled and written here."""
    if int(physics.mjm.opt.integrator) != EULER:
        raise SimulationError("LIBERO port: the controller runs between step1 and step2, which needs the Euler "
                              f"integrator; this model uses integrator {int(physics.mjm.opt.integrator)}")
    if hasattr(physics, "control_substep"):
        controller = physics.warp_controller(cfg, facts)
        controller.load(state, action)
        if sampler is not None:
            physics.control_substeps(controller, cfg.substeps, sampler, images, drawn)
            return controller.state(state)
        for k in range(cfg.substeps):
            physics.control_substep(controller, k == 0)
            if after_substep is not None:
                after_substep()
        return controller.state(state)
    xp = physics.xp
    arm, fingers = xp.asarray(np.asarray(facts["arm_actuators"])), xp.asarray(np.asarray(facts["gripper_actuators"]))
    ctrl = physics.view(physics.d.ctrl)
    for k in range(cfg.substeps):
        physics.step1()
        tau, grip, state = C.substep(xp, cfg, state, physics.read(), action, k == 0)
        ctrl[:, arm] = tau.astype(ctrl.dtype)
        ctrl[:, fingers] = grip.astype(ctrl.dtype)
        physics.step2()
        if after_substep is not None:
            after_substep()
    return state
