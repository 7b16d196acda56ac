"""Meta-World v3 behind the seam (``benchmark: {name: metaworld, task: reach-v3}``).

Native environment: ``metaworld.MT1(task, seed=goal_seed)`` gives the task's 50 fixed
goal/object variations (``train_tasks``); episode ``seed`` uses variation ``seed % 50``
and ``env.seed(seed)``, so 50 consecutive seeds cover every variation once (the MT1
evaluation protocol, made deterministic). Seeds ``s`` and ``s + 50`` are therefore the same
episode. ``variation: ml1`` takes ``metaworld.ML1(task, seed=goal_seed).test_tasks`` instead: ML1's
50 held-out goal variations (its meta-test set), ``seed % 50`` likewise; as in ML1, the goal is not in
the observation (its last 3 values are zeros). ``variation: sampled`` instead draws each episode's object and goal positions from
the task's own reset distribution (the one MT1 draws its 50 from) with the episode seed
(Meta-World's ``seeded_rand_vec`` path after ``env.seed(seed)``): every seed its own episode,
none of them one of MT1's 50, so demonstrations recorded that way leave the MT1 variations
that ``simseam eval metaworld_mt10`` runs unseen. ``variation: lerobot`` is LeRobot's own
Meta-World env (``lerobot-eval --env.type=metaworld``, lerobot/envs/metaworld.py): MT1 variation 0's
settings, then each reset draws from NumPy's *global* generator (Meta-World's unseeded path; its
``reset(seed=...)`` ignores the seed); episode ``seed`` is ``np.random.seed(seed)`` then that reset,
which is what ``lerobot-eval --seed=<seed>`` runs as its first episode (its later episodes continue
the global stream, each success drawing once more for the env's own reset). Each reset starts from freshly reset MuJoCo
data (``mj_resetData``), so an episode is the same whether it is the first of its
environment or the hundredth (MuJoCo's solver warm start would otherwise carry over).

Mapping to the seam:

- action: Meta-World's own ``[dx, dy, dz, grip]`` in [-1, 1] (CARTESIAN_DELTA, 1 cm per unit
  per step of the mocap target; grip -1 open, +1 closed), clipped to the bounds;
- ``images``: ``{"camera1": <camera>}`` (default ``corner2``) at ``image_size`` (default 224x224),
  exactly what ``env.render()`` returns for that camera; ``camera: [corner, gripperPOV]`` (a list)
  gives ``camera1``, ``camera2``, ... in that order, each what ``env.render()`` returns with the env's
  renderer pointed at it; ``cameras: false`` declares none (a
  state-only rollout: ``simseam collect --no-cameras`` and a state policy's ``run`` set it).
  ``camera_pos: [x, y, z]`` moves the (first) camera (LeRobot's env puts ``corner2`` at
  ``[0.75, 0.075, 0.7]``); ``image_flip: true`` turns every image by 180 degrees (LeRobot flips
  ``corner2``'s both axes: Meta-World renders it upside down);
- ``state``: the 39-D Meta-World observation (hand xyz, gripper opening, two object poses, the
  previous frame of those, the goal), cast to float32 (native: float64); ``state: agent_pos``
  keeps its first 4 (hand xyz, gripper opening): LeRobot's ``agent_pos``;
- ``environment_state`` (``environment_state: true``, the default): the 17 task slots of that
  observation, the two object poses and the goal (``state[4:18]`` and ``state[36:39]``), under
  the seam's key for a task's object state: what LeRobot's ACT reads as
  ``observation.environment_state`` (it refuses a state-only policy without it or a camera). It
  repeats what ``state`` already holds; ``state`` itself is unchanged;
- ``joint_positions`` / ``joint_velocities``: the Sawyer's 7 arm joints and 2 finger joints;
- ``expert_action`` (privileged rollouts only, i.e. ``--policy scripted``): the action of
  Meta-World's scripted expert for this task (``metaworld.policies``) on the full-precision
  observation; ``reward`` and ``success`` are the benchmark's own (``info["success"]``); the
  other ``info`` values are the diagnostics.

Imports numpy and simseam.seam at module level; metaworld and mujoco only in ``make_rollout``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.base import (
    BenchmarkRollout,
    check_image_size,
    check_int,
    check_keys,
    mount_rpy,
    observation_spec,
)
from simseam.seam import (
    OBS_ENV_STATE,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
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
from simseam.seam.errors import did_you_mean

NAME = "metaworld"
HAS_EXPERT = True  # metaworld.policies: one scripted expert per task
CAMERAS = ("corner", "corner2", "corner3", "topview", "behindGripper", "gripperPOV")
CAMERA_OPTION = "cameras"  # on unless turned off: build_rollout turns it off when nothing reads images
VARIATIONS = ("mt1", "ml1", "sampled", "lerobot")
STATES = ("full", "agent_pos")
DEFAULTS = {"camera": "corner2", "image_size": [224, 224], "max_steps": 500, "goal_seed": 0, "expert": False,
            "cameras": True, "variation": "mt1", "environment_state": True, "camera_pos": None,
            "image_flip": False, "state": "full"}
DIAGNOSTICS = ("near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target", "unscaled_reward")
ROBOT_JOINTS = ("right_j0", "right_j1", "right_j2", "right_j3", "right_j4", "right_j5", "right_j6", "r_close",
                "l_close")
STATE_NAMES = tuple(
    ["hand_x", "hand_y", "hand_z", "gripper_distance"]
    + [f"obj1_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    + [f"obj2_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    + [f"prev_{i}" for i in range(18)] + ["goal_x", "goal_y", "goal_z"])
AGENT_POS = 4  # LeRobot's agent_pos: hand xyz + gripper opening, the observation's first 4
ENV_STATE_SLOTS = (*range(4, 18), 36, 37, 38)  # obj1 pose, obj2 pose, goal: the task's part of the 39-D observation
ENV_STATE_NAMES = tuple(STATE_NAMES[i] for i in ENV_STATE_SLOTS)
N_GOALS = 50


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", "task", *DEFAULTS}, where)
    task = config.get("task")
    if not isinstance(task, str) or not task.endswith("-v3"):
        raise ConfigError(f"{where}.task: a Meta-World v3 task name such as 'reach-v3' is required, got {task!r} "
                          "(`simseam benchmarks list metaworld` lists them)")
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    camera_names(out, where)
    out["image_size"] = check_image_size(out["image_size"], where)
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps")
    out["goal_seed"] = check_int(out["goal_seed"], f"{where}.goal_seed", low=0)
    for key in ("expert", "cameras", "environment_state", "image_flip"):
        if not isinstance(out[key], bool):
            raise ConfigError(f"{where}.{key}: expected true or false, got {out[key]!r}")
    if out["variation"] not in VARIATIONS:
        raise ConfigError(f"{where}.variation: {out['variation']!r}; one of {list(VARIATIONS)} (mt1: MT1's 50 fixed "
                          "variations, seed % 50; ml1: ML1's 50 held-out test variations, seed % 50, goal unobserved; "
                          "sampled: a fresh draw from the task's reset distribution per seed; "
                          "lerobot: LeRobot's env, a draw from NumPy's global generator after np.random.seed(seed))")
    if out["state"] not in STATES:
        raise ConfigError(f"{where}.state: {out['state']!r}; one of {list(STATES)} (full: the 39-D observation; "
                          "agent_pos: its first 4, hand xyz and gripper opening, as LeRobot's env)")
    pos = out["camera_pos"]
    if pos is not None:
        if not (isinstance(pos, (list, tuple)) and len(pos) == 3
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in pos)):
            raise ConfigError(f"{where}.camera_pos: expected [x, y, z] in metres, got {pos!r}")
        out["camera_pos"] = [float(x) for x in pos]
    return out


def camera_names(config: dict[str, Any], where: str = "benchmark") -> tuple[str, ...]:
    """The cameras of ``config['camera']`` (one name, or a list of distinct names), in the order of their
    feature keys ``camera1``, ``camera2``, ...; an unknown name is a one-line error naming it and the task."""
    cams = config["camera"]
    names = (cams,) if isinstance(cams, str) else tuple(cams) if isinstance(cams, (list, tuple)) else ()
    if not names or len(set(names)) != len(names) or not all(isinstance(c, str) for c in names):
        raise ConfigError(f"{where}.camera: a Meta-World camera name or a list of distinct ones, got {cams!r}")
    for name in names:
        if name not in CAMERAS:
            raise ConfigError(f"{where}.camera: {name!r} is not a Meta-World camera (task {config.get('task')!r}); "
                              f"one of {list(CAMERAS)}{did_you_mean(name, CAMERAS)}")
    return names


def camera_sensors(m, d, config: dict[str, Any]) -> tuple:
    """The ``SensorFacts`` of ``config``'s cameras (``camera1``, ...) in the state of ``d`` (a reset): a camera
    on the world at its world pose, one on a moving body (``gripperPOV`` on the hand) at its pose in that
    body's frame; turned half a turn about the view axis when ``image_flip``."""
    h, w = config["image_size"]
    out = []
    for i, name in enumerate(camera_names(config)):
        cam = m.camera(name).id
        body = int(m.cam_bodyid[cam])
        rot = d.xmat[body].reshape(3, 3)
        xmat = rot.T @ d.cam_xmat[cam].reshape(3, 3)
        if config["image_flip"]:
            xmat[:, :2] *= -1  # the image turned by 180 degrees: the camera rolled half a turn about its view axis
        xyz = rot.T @ (d.cam_xpos[cam] - d.xpos[body])
        out.append(SensorFacts(name=name, kind="rgb", parent="world" if body == 0 else m.body(body).name,
                               xyz=tuple(float(x) for x in xyz), rpy=mount_rpy(xmat), feature_key=f"camera{i + 1}",
                               width=w, height=h, fovy_deg=float(m.cam_fovy[cam])))
    return tuple(out)


def instruction(task: str) -> str:
    """Meta-World has no language instructions: the task's name in words ("button press topdown")."""
    return task.removesuffix("-v3").replace("-", " ")


def catalog() -> dict[str, Any]:
    """Suites and tasks (run in the backend's venv by ``simseam benchmarks list``)."""
    import metaworld

    tasks = list(metaworld.MT1.ENV_NAMES)
    mt10 = list(metaworld.MT10().train_classes)
    return {"suites": {"MT50": tasks, "MT10": mt10},
            "tasks": {t: instruction(t) for t in tasks}}


def sawyer_joints(m) -> tuple:
    """The Sawyer's 7 arm and 2 finger joints with their limits (``JointFacts``), from a compiled Meta-World
    model (the native one here, MuJoCo Warp's port's compiled copy there)."""
    return tuple(JointFacts(j, "arm" if j.startswith("right_j") else "gripper",
                            float(m.jnt_range[m.joint(j).id][0]), float(m.jnt_range[m.joint(j).id][1]))
                 for j in ROBOT_JOINTS)


def extra_fields(expert: bool, environment_state: bool) -> dict:
    """The observation keys a Meta-World rollout declares beyond the common ones: the expert's action
    (privileged) and the task's object state."""
    extra = {OBS_EXPERT_ACTION: FieldSpec("float32", (4,), presence="declared")} if expert else {}
    if environment_state:
        extra[OBS_ENV_STATE] = FieldSpec("float32", (len(ENV_STATE_SLOTS),), names=ENV_STATE_NAMES,
                                         presence="declared")
    return extra


class MetaWorldRollout(BenchmarkRollout):
    def __init__(self, config: dict[str, Any]):
        import metaworld
        import mujoco

        self._mj = mujoco
        self.config = config
        name = config["task"]
        if name not in metaworld.MT1.ENV_NAMES:
            raise ConfigError(f"benchmark.task: unknown Meta-World task {name!r}"
                              f"{did_you_mean(name, metaworld.MT1.ENV_NAMES)}; known: {', '.join(metaworld.MT1.ENV_NAMES)}")
        self._bench = metaworld.MT1(name, seed=config["goal_seed"])
        h, w = config["image_size"]
        cams = camera_names(config)
        self.env = self._bench.train_classes[name](render_mode="rgb_array", camera_name=cams[0], width=w, height=h)
        self.env.max_path_length = 10**9  # the seam truncates at max_steps; stepping on continues the physics
        self._expert = None
        self._ml1: list | None = None  # ML1's test tasks, made on the first ml1 reset
        if config["expert"]:
            from metaworld.policies import ENV_POLICY_MAP

            self._expert = ENV_POLICY_MAP[name]()
        m = self.env.model
        if config["camera_pos"] is not None:
            m.cam_pos[m.camera(cams[0]).id] = config["camera_pos"]
        self._camera_ids = {f"camera{i + 1}": m.camera(c).id for i, c in enumerate(cams)}
        self._qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in ROBOT_JOINTS])
        self._vadr = np.array([m.jnt_dofadr[m.joint(j).id] for j in ROBOT_JOINTS])
        self._native_reset(0)  # camera poses and the first observation
        sensors = camera_sensors(m, self.env.data, config) if config["cameras"] else ()
        joints = sawyer_joints(m)
        extra = extra_fields(self._expert, config["environment_state"])
        step = float(self.env.action_scale)
        spec = RolloutSpec(
            robot=RobotFacts(name="sawyer", base_link="world", tool_link="hand", joints=joints, sensors=sensors),
            task=TaskSpec(name=name, instruction=instruction(name), max_steps=config["max_steps"],
                          diagnostics=DIAGNOSTICS),
            observation=observation_spec({k: (h, w) for k in self._camera_ids} if config["cameras"] else {},
                                         STATE_NAMES[:AGENT_POS] if config["state"] == "agent_pos" else STATE_NAMES,
                                         ROBOT_JOINTS, extra),
            action=ActionSpec(ControlMode.CARTESIAN_DELTA,
                              (ActionSlot("dx", "arm", -1.0, 1.0, f"{step} m"),
                               ActionSlot("dy", "arm", -1.0, 1.0, f"{step} m"),
                               ActionSlot("dz", "arm", -1.0, 1.0, f"{step} m"),
                               ActionSlot("grip", "grip", -1.0, 1.0, "-1 open, +1 closed")),
                              max_translation=step),
            engine=f"metaworld-{metaworld.__version__ if hasattr(metaworld, '__version__') else '3'}"
                   f"/mujoco-{mujoco.__version__}",
            control_hz=1.0 / (m.opt.timestep * self.env.frame_skip),
            backend="inprocess",
            capabilities=("privileged",) if self._expert else (),
        )
        super().__init__(spec)

    def _native_reset(self, seed: int) -> None:
        self._mj.mj_resetData(self.env.model, self.env.data)
        if self.config["variation"] == "lerobot":
            self.env.set_task(self._bench.train_tasks[0])  # LeRobot's env: variation 0's settings ...
            self.env._freeze_rand_vec = False  # ... then every reset draws from NumPy's global generator
            self.env.seeded_rand_vec = False
            np.random.seed(seed)  # what lerobot-eval's set_seed(seed) does before its first episode
        elif self.config["variation"] == "sampled":
            self.env.set_task(self._bench.train_tasks[0])  # the task's observability and settings ...
            self.env._freeze_rand_vec = False  # ... then its reset draws from env.np_random (seeded below)
            self.env.seeded_rand_vec = True
        elif self.config["variation"] == "ml1":
            self.env.set_task(self._ml1_test()[seed % N_GOALS])  # ML1's held-out goals (its meta-test set)
        else:
            self.env.set_task(self._bench.train_tasks[seed % N_GOALS])
        self.env.seed(seed)
        self._obs, _ = self.env.reset()

    def _ml1_test(self) -> list:
        """``metaworld.ML1(task, seed=goal_seed).test_tasks``, made once (50 resets' worth of work)."""
        if self._ml1 is None:
            import metaworld

            self._ml1 = metaworld.ML1(self.config["task"], seed=self.config["goal_seed"]).test_tasks
        return self._ml1

    def _native_step(self, action: np.ndarray):
        self._obs, reward, _term, _trunc, info = self.env.step(action)
        return float(reward), bool(info["success"]), {k: float(info[k]) for k in DIAGNOSTICS}

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        d = self.env.data
        obs = {
            OBS_IMAGES: {k: self._render_camera(k) for k in self.spec.observation.images if request.wants_image(k)},
            OBS_STATE: np.asarray(self._obs[:AGENT_POS] if self.config["state"] == "agent_pos" else self._obs,
                                  dtype=np.float32),
            OBS_JOINT_POSITIONS: d.qpos[self._qadr].astype(np.float32),
            OBS_JOINT_VELOCITIES: d.qvel[self._vadr].astype(np.float32),
        }
        if self.config["environment_state"]:
            obs[OBS_ENV_STATE] = np.asarray(self._obs, dtype=np.float32)[list(ENV_STATE_SLOTS)]
        if self._expert is not None:
            obs[OBS_EXPERT_ACTION] = np.asarray(self._expert.get_action(self._obs), dtype=np.float32)
        return obs

    def _render_camera(self, key: str) -> np.ndarray:
        self.env.mujoco_renderer.camera_id = self._camera_ids[key]  # what env.render() draws, for this camera
        img = self.env.render()
        return np.ascontiguousarray(img[::-1, ::-1] if self.config["image_flip"] else img)

    def _sim_time_s(self) -> float:
        return float(self.env.data.time)

    def _native_close(self) -> None:
        self.env.close()


def make_rollout(config: dict[str, Any]) -> MetaWorldRollout:
    import warnings

    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")  # metaworld.policies, per step
    return MetaWorldRollout(config)
