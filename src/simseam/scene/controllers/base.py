"""The kinematic base's twist: ``[vx, vy, wz]`` in the base frame (m/s, m/s, rad/s).

Bounds: each of ``vx``, ``vy`` within +-max_linear and ``[vx, vy]`` within
max_linear in norm; ``wz`` within +-max_angular. The scene integrates the twist
over the control period (``scene.base_motion.KinematicBase``).
"""

from __future__ import annotations

from simseam.robot.spec import KinematicBaseSpec
from simseam.seam import ActionSlot, NormBound


class TwistBase:
    group = "base"

    def __init__(self, spec: KinematicBaseSpec):
        lin, ang = float(spec.max_linear), float(spec.max_angular)
        self.slots = (ActionSlot("vx", "base", -lin, lin, "m/s"), ActionSlot("vy", "base", -lin, lin, "m/s"),
                      ActionSlot("wz", "base", -ang, ang, "rad/s"))
        self.norm_bounds = (NormBound(("vx", "vy"), lin),)
