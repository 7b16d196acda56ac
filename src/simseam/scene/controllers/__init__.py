"""Controllers: each owns one group of action slots, its meaning and its bounds.

- ``arm``: ``JointPositionArm`` (absolute joint targets) or ``CartesianDeltaArm``
  (end-effector deltas solved by the scene's IK), both rate-limited by the URDF
  joint speed limits;
- ``gripper``: ``Gripper`` (-1 open .. +1 closed -> finger positions);
- ``base``: ``TwistBase`` (``[vx, vy, wz]`` for a kinematic holonomic base).

``ManifestScene`` composes them; their ``slots`` make up the rollout's
``ActionSpec``, whose ``clip`` is applied once, before any controller sees an action.
"""

from simseam.scene.controllers.arm import ArmController, CartesianDeltaArm, JointPositionArm
from simseam.scene.controllers.base import TwistBase
from simseam.scene.controllers.gripper import Gripper

__all__ = ["ArmController", "CartesianDeltaArm", "Gripper", "JointPositionArm", "TwistBase"]
