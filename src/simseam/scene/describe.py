"""The ``RolloutSpec`` of a manifest scene: robot facts, observation keys, task.

This is the one machine-readable statement of what a ``ManifestScene``
observes; the scene's ``observe`` fills exactly these keys and the sidecar
forwards this spec unchanged.
"""

from __future__ import annotations

import dataclasses

from simseam.robot.spec import RobotSpec
from simseam.robot.urdf import UrdfModel
from simseam.seam import (
    CAP_LINK_POSES,
    CAP_PRIVILEGED,
    OBS_BASE_POSE,
    OBS_DEPTH_POINTS,
    OBS_ENV_STATE,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_LINK_POSES,
    OBS_PRIVILEGED,
    OBS_SCAN,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ActionSpec,
    BaseFacts,
    FieldSpec,
    JointFacts,
    LinkFacts,
    ObservationSpec,
    RobotFacts,
    RolloutSpec,
    TaskSpec,
)


def robot_facts(spec: RobotSpec, urdf: UrdfModel, image_sizes: dict[str, tuple[int, int]]) -> RobotFacts:
    """``image_sizes``: sensor name -> (H, W) as rendered (the scene may override the manifest's)."""
    by_child = {j.child: j for j in urdf.joints}
    links = []
    for name in urdf.links:
        j = by_child.get(name)
        links.append(LinkFacts(name) if j is None else
                     LinkFacts(name, j.parent, j.name, j.type, tuple(j.xyz), tuple(j.rpy), tuple(j.axis)))
    if spec.tcp is not None:  # the manifest's tool frame: a virtual link fixed to its parent
        t = spec.tcp
        links.append(LinkFacts(t.name, t.parent, f"{t.name}_joint", "fixed", tuple(t.xyz), tuple(t.rpy)))
    sensors = tuple(dataclasses.replace(s, height=h, width=w) for s in spec.sensors
                    for h, w in [image_sizes.get(s.name, (s.height, s.width))])
    kb = spec.kinematic_base  # the seam's facts of the scene-only subclasses (what crosses in the spec)
    return RobotFacts(
        name=spec.name, base_link=spec.base_link, tool_link=spec.ee_link, urdf=spec.urdf,
        joints=tuple(JointFacts(j.name, j.role, j.lower, j.upper, j.max_velocity, j.sim_name) for j in spec.joints),
        gripper=spec.gripper,
        base=None if kb is None else BaseFacts(kb.joints, kb.max_linear, kb.max_angular, kb.height),
        sensors=sensors, links=tuple(links))


def observation_spec(robot: RobotFacts, cameras: dict[str, tuple[int, int]], state_names: tuple[str, ...],
                     privileged_objects: tuple[str, ...] | None, *, renders: bool,
                     env_state_names: tuple[str, ...] | None = None) -> ObservationSpec:
    """The keys a manifest scene observes. ``cameras``: feature key -> (H, W) of its RGB images;
    ``renders``: False for a state-only scene (no images, no depth clouds); ``privileged_objects``:
    names in ``privileged['objects']``, or None when the scene is not privileged; ``env_state_names``:
    the slots of ``environment_state``, or None when the scene does not observe it."""
    cameras = cameras if renders else {}
    n = len(robot.joints)
    f32 = "float32"
    fields = {
        OBS_IMAGES: FieldSpec("dict", entries={k: FieldSpec("uint8", (h, w, 3), unit="rgb8")
                                               for k, (h, w) in cameras.items()}),
        OBS_STATE: FieldSpec(f32, (len(state_names),), names=state_names),
        OBS_TASK: FieldSpec("str"),
        OBS_JOINT_POSITIONS: FieldSpec(f32, (n,), unit="rad|m", names=robot.joint_names),
        OBS_JOINT_VELOCITIES: FieldSpec(f32, (n,), unit="rad/s|m/s", names=robot.joint_names),
        OBS_SIM_TIME_NS: FieldSpec("int", unit="ns"),
    }
    if robot.base is not None:
        fields[OBS_BASE_POSE] = FieldSpec(f32, (3,), "declared", "m, m, rad (world)", ("x", "y", "yaw"))
    lidars = robot.sensors_of("lidar_2d")
    if lidars:
        fields[OBS_SCAN] = FieldSpec(f32, (lidars[0].beams,), "declared", "m (base_link)")
    depth = robot.sensors_of("depth")
    if depth and renders:
        fields[OBS_DEPTH_POINTS] = FieldSpec("dict", (), "on_request", "m (base_link)",
                                             entries={s.name: FieldSpec(f32, (-1, 3)) for s in depth})
    fields[OBS_LINK_POSES] = FieldSpec("dict", (), "on_request", "m, quaternion wxyz (base_link)",
                                       entries={link.name: FieldSpec(f32, (7,)) for link in robot.links})
    if env_state_names is not None:
        fields[OBS_ENV_STATE] = FieldSpec(f32, (len(env_state_names),), "declared", "m, quaternion wxyz (base_link)",
                                          env_state_names)
    if privileged_objects is not None:
        fields[OBS_PRIVILEGED] = FieldSpec("dict", (), "declared", "m, quaternion wxyz (base_link)", entries={
            "eef_pose": FieldSpec("float64", (7,)),
            "objects": FieldSpec("dict", entries={k: FieldSpec("float64", (7,)) for k in privileged_objects})})
    return ObservationSpec(fields)


def rollout_spec(*, robot: RobotFacts, observation: ObservationSpec, action: ActionSpec, task: TaskSpec,
                 engine: str, control_hz: float, privileged: bool) -> RolloutSpec:
    caps = (CAP_LINK_POSES,) + ((CAP_PRIVILEGED,) if privileged else ())
    return RolloutSpec(robot=robot, task=task, observation=observation, action=action, engine=engine,
                       control_hz=float(control_hz), backend="inprocess", capabilities=caps)
