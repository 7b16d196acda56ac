"""robosuite 1.5 behind the seam (``benchmark: {name: robosuite, task: Lift, robot: Panda}``).

Native environment: ``robosuite.make(task, robots=robot, ...)`` with its default composite
controller (OSC_POSE arm + gripper), offscreen cameras ``agentview`` and ``robot0_eye_in_hand``
at ``image_size``; episode ``seed`` sets the env's random generator (``env.rng =
np.random.default_rng(seed)``) and resets (a hard reset rebuilds the model, and the object
placement draws from it: ``reseed`` hands it to the placement samplers too), so an episode
depends on its seed alone.

Mapping to the seam:

- action: robosuite's own ``env.action_spec`` (for one arm with OSC_POSE: ``[dx, dy, dz, dax, day,
  daz, grip]`` in [-1, 1], 0.05 m and 0.5 rad per unit, grip -1 open, +1 closed), CARTESIAN_DELTA,
  clipped to the spec's bounds;
- ``images``: ``camera1`` = ``agentview``, ``camera2`` = ``robot0_eye_in_hand`` (``cameras:`` picks
  others), flipped upright (robosuite renders in OpenGL's bottom-up order); a camera not requested
  renders nothing that step (``robosuite_cameras``);
- ``state``: ``[eef_pos(3), axis-angle of eef_quat(3), gripper_qpos(n)]`` (as LIBERO and bowl_plate);
- ``joint_positions`` / ``joint_velocities``: the arm's joints, then the gripper's;
- reward: robosuite's (sparse unless ``reward_shaping: true``); success: the env's ``_check_success()``.

Imports numpy and simseam.seam at module level; robosuite only in ``make_rollout``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.base import BenchmarkRollout, check_image_size, check_int, check_keys, observation_spec
from simseam.backends.libero import quat_to_axis_angle
from simseam.backends.robosuite_cameras import CameraSwitch, release_render_context
from simseam.seam import (
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    JointFacts,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)

NAME = "robosuite"
HAS_EXPERT = False
TASKS = {
    "Lift": "lift the cube", "Stack": "stack the red cube on the green cube",
    "PickPlace": "put each object into its bin", "PickPlaceMilk": "put the milk into its bin",
    "PickPlaceBread": "put the bread into its bin", "PickPlaceCereal": "put the cereal into its bin",
    "PickPlaceCan": "put the can into its bin", "NutAssembly": "fit each nut onto its peg",
    "NutAssemblySquare": "fit the square nut onto its peg", "NutAssemblyRound": "fit the round nut onto its peg",
    "Door": "open the door", "Wipe": "wipe the markings off the table", "ToolHang": "hang the tool on the stand",
}
DEFAULTS = {"task": "Lift", "robot": "Panda", "cameras": ["agentview", "robot0_eye_in_hand"],
            "image_size": [128, 128], "max_steps": 500, "control_freq": 20, "reward_shaping": False}


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", *DEFAULTS}, where)
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    if out["task"] not in TASKS:
        raise ConfigError(f"{where}.task: single-arm robosuite tasks are {sorted(TASKS)}; got {out['task']!r}")
    if not isinstance(out["robot"], str) or not out["robot"]:
        raise ConfigError(f"{where}.robot: a robosuite robot name such as 'Panda' or 'Sawyer', got {out['robot']!r}")
    cams = out["cameras"]
    if not (isinstance(cams, list) and 1 <= len(cams) <= 9 and all(isinstance(c, str) and c for c in cams)):
        raise ConfigError(f"{where}.cameras: a list of robosuite camera names, got {cams!r}")
    out["image_size"] = check_image_size(out["image_size"], where)
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps")
    out["control_freq"] = check_int(out["control_freq"], f"{where}.control_freq")
    if not isinstance(out["reward_shaping"], bool):
        raise ConfigError(f"{where}.reward_shaping: expected true or false, got {out['reward_shaping']!r}")
    return out


def catalog() -> dict[str, Any]:
    import robosuite

    known = set(robosuite.ALL_ENVIRONMENTS)
    return {"suites": {"robosuite": [t for t in TASKS if t in known]}, "tasks": {t: TASKS[t] for t in TASKS if t in known}}


def make_native(config: dict[str, Any]):
    """The robosuite env the backend drives (the fidelity test builds the same one without simseam)."""
    import robosuite

    h, w = config["image_size"]
    return robosuite.make(config["task"], robots=config["robot"], has_renderer=False, has_offscreen_renderer=True,
                          use_camera_obs=True, camera_names=list(config["cameras"]), camera_heights=h,
                          camera_widths=w, control_freq=config["control_freq"], horizon=10**9,
                          reward_shaping=config["reward_shaping"])


def reseed(env, seed: int) -> None:
    """Make the next ``env.reset()`` depend on ``seed`` alone: robosuite 1.5 draws object sizes (hard
    reset), robot noise and placements from ``env.rng``, but a task's placement sampler keeps the
    generator it was built with, so it (and its sub-samplers) get the new one too."""
    rng = np.random.default_rng(seed)
    env.rng = rng
    todo = [getattr(env, "placement_initializer", None)]
    while todo:
        sampler = todo.pop()
        if sampler is None:
            continue
        sampler.rng = rng
        todo.extend(getattr(sampler, "samplers", {}).values())


class RobosuiteRollout(BenchmarkRollout):
    def __init__(self, config: dict[str, Any]):
        import mujoco
        import robosuite

        self.env = make_native(config)
        keys = [f"camera{i + 1}" for i in range(len(config["cameras"]))]
        self._switch = CameraSwitch({k: f"{c}_image" for k, c in zip(keys, config["cameras"])})
        self._obs: dict = {}
        self._native_reset(0)
        robot = self.env.robots[0]
        arm = robot.arms[0] if hasattr(robot, "arms") else "right"
        grip = robot.gripper[arm] if isinstance(robot.gripper, dict) else robot.gripper
        m = self.env.sim.model
        joints = tuple(JointFacts(j, "arm", *(float(x) for x in m.jnt_range[m.joint_name2id(j)]))
                       for j in robot.robot_joints) + tuple(JointFacts(j, "gripper") for j in grip.joints)
        self._n_grip = len(grip.joints)
        low, high = self.env.action_spec
        if len(low) != 7:
            raise ConfigError(f"benchmark: {config['robot']} on {config['task']} has {len(low)}-D actions; this "
                              "backend maps one arm with OSC_POSE + gripper (7-D)")
        ctrl = robot.part_controllers[arm] if hasattr(robot, "part_controllers") else robot.controller
        h, w = config["image_size"]
        sensors = tuple(SensorFacts(name=c, kind="rgb", parent="world", xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0),
                                    feature_key=k, width=w, height=h) for k, c in zip(keys, config["cameras"]))
        names = ("dx", "dy", "dz", "dax", "day", "daz", "grip")
        state = ("eef_x", "eef_y", "eef_z", "eef_ax", "eef_ay", "eef_az") + tuple(f"finger_{i}" for i in
                                                                               range(self._n_grip))
        spec = RolloutSpec(
            robot=RobotFacts(name=f"{config['robot'].lower()}_robosuite", base_link="robot0_base",
                             tool_link="gripper0_right_grip_site", joints=joints, sensors=sensors),
            task=TaskSpec(name=config["task"], instruction=TASKS[config["task"]], max_steps=config["max_steps"]),
            observation=observation_spec({k: (h, w) for k in keys}, state, tuple(j.name for j in joints)),
            action=ActionSpec(ControlMode.CARTESIAN_DELTA,
                              tuple(ActionSlot(n, "grip" if n == "grip" else "arm", float(lo), float(hi))
                                    for n, lo, hi in zip(names, low, high)),
                              max_translation=float(np.max(ctrl.output_max[:3])),
                              max_rotation=float(np.max(ctrl.output_max[3:6]))),
            engine=f"robosuite-{robosuite.__version__}/mujoco-{mujoco.__version__}",
            control_hz=float(config["control_freq"]),
        )
        super().__init__(spec)

    def _native_reset(self, seed: int) -> None:
        self._switch.apply(self.env, ObsRequest())  # every camera real for the reset
        reseed(self.env, seed)
        release_render_context(self.env.sim)  # a hard reset drops this simulation
        self._obs = self.env.reset()
        self._switch.reset()  # a hard reset rebuilt the observables

    def step(self, action, observe=None):
        self._switch.apply(self.env, observe or ObsRequest())
        return super().step(action, observe)

    def _native_step(self, action: np.ndarray):
        self._obs, reward, _done, _info = self.env.step(action)
        return float(reward), bool(self.env._check_success()), {}

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        o = self._obs
        state = np.concatenate([o["robot0_eef_pos"], quat_to_axis_angle(o["robot0_eef_quat"]),
                                o["robot0_gripper_qpos"]])
        return {
            OBS_IMAGES: {k: self._render_camera(k) for k in self.spec.observation.images if request.wants_image(k)},
            OBS_STATE: state.astype(np.float32),
            OBS_JOINT_POSITIONS: np.concatenate([o["robot0_joint_pos"], o["robot0_gripper_qpos"]]).astype(np.float32),
            OBS_JOINT_VELOCITIES: np.concatenate([o["robot0_joint_vel"], o["robot0_gripper_qvel"]]).astype(np.float32),
        }

    def _render_camera(self, key: str) -> np.ndarray:
        return np.ascontiguousarray(self._switch.frame(self._obs, key)[::-1])

    def _sim_time_s(self) -> float:
        return float(self.env.sim.data.time)

    def _native_close(self) -> None:
        self.env.close()


def make_rollout(config: dict[str, Any]) -> RobosuiteRollout:
    return RobosuiteRollout(config)
